//! Each machine's ResultManagement (OPC 40001-101 Machinery Result
//! Transfer): a result per finished order of the cell, its metadata from
//! the order (its id, the job order, the recipe and its versions, the
//! times, OK or not OK) and its content the order's product record as
//! `falc order show --json` gives it; GetLatestResult and GetResultById,
//! and a ResultReadyEvent when an order ends. This module lays it out,
//! names the method a node id is, and says (sans-I/O) which order is
//! which result and which ended since the last look; `structures` encodes
//! a result, `server` answers the methods and sends the events.

use crate::machinery::{Machine, Namespaces};
use falc_model::product::OrderRecord;
use falc_model::records::{Order, OrderState};
use falc_opcua_models::result::ids::{DataTypeId as ResultType, ObjectTypeId as ResultObject};
use opcua::nodes::ReferenceDirection;
use opcua::server::address_space::{AddressSpace, MethodBuilder, ObjectBuilder};
use opcua::types::{
    Argument, AttributeId, DataTypeId, LocalizedText, NodeId, NumericRange, QualifiedName,
    ReferenceTypeId, UAString, Variant,
};
use std::collections::BTreeSet;

/// `Error` of a result method: none.
pub const OK: i32 = 0;
/// `Error` of a result method: no such result (no order of the cell
/// ended yet, or none with that ResultId).
pub const NO_RESULT: i32 = -1;
/// `Error` of a result method: the order has not ended yet.
pub const NOT_ENDED: i32 = -2;

/// A method of a machine's ResultManagement.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ResultMethod {
    /// GetLatestResult(Timeout).
    Latest,
    /// GetResultById(ResultId, Timeout).
    ById,
}

const OBJECT: &str = "ResultManagement";

impl ResultMethod {
    /// Both methods.
    pub const ALL: [ResultMethod; 2] = [Self::Latest, Self::ById];

    /// Its browse name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Latest => "GetLatestResult",
            Self::ById => "GetResultById",
        }
    }

    /// Its node id under machine `m`.
    pub fn id(self, m: &Machine) -> String {
        m.id(&format!("{OBJECT}.{}", self.name()))
    }
}

/// The machine and method that node id `id` (of the gateway's namespace)
/// is, among `machines`.
pub fn method<'a>(
    id: &str,
    mut machines: impl Iterator<Item = &'a Machine>,
) -> Option<(&'a Machine, ResultMethod)> {
    machines.find_map(|m| {
        ResultMethod::ALL
            .into_iter()
            .find(|r| r.id(m) == id)
            .map(|r| (m, r))
    })
}

/// A result as FALC makes it (ResultDataType: the fields it fills).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MachineResult {
    /// ResultId: the order's id.
    pub id: String,
    /// JobId: the job order it carried out, if any.
    pub job: Option<String>,
    /// ExternalRecipeId: the cell recipe's name.
    pub recipe: String,
    /// InternalRecipeId: the cell recipe's version (`v3 <sha-256>`), if
    /// the record has it.
    pub recipe_version: Option<String>,
    /// ProcessingTimes: start and end (ms since the Unix epoch).
    pub started_ms: Option<i64>,
    /// End.
    pub ended_ms: i64,
    /// ResultEvaluation: OK (done) or not OK.
    pub ok: bool,
    /// ResultEvaluationDetails: how it ended, in words.
    pub details: String,
    /// ResultContent: the product record, as JSON.
    pub content: Option<String>,
}

/// The result of `order`, with its product record `record` if the
/// operator gave it; None while the order has not ended.
pub fn of(order: &Order, record: Option<&OrderRecord>) -> Option<MachineResult> {
    let ended_ms = order.ended_ms.filter(|_| finished(order))?;
    let recipe_version = record
        .and_then(|r| r.runs.last())
        .and_then(|run| run.recipes.first())
        .map(|u| format!("v{} {}", u.version, u.hash));
    Some(MachineResult {
        id: order.id.to_string(),
        job: order.job_order.clone(),
        recipe: order.recipe.clone(),
        recipe_version,
        started_ms: order.started_ms,
        ended_ms,
        ok: order.state == OrderState::Done,
        details: format!(
            "order {} ({}) {}{}",
            order.id,
            order.recipe,
            order.state,
            order
                .result
                .as_deref()
                .map(|r| format!(": {r}"))
                .unwrap_or_default()
        ),
        content: record.and_then(|r| serde_json::to_string(r).ok()),
    })
}

/// Whether `o` has finished: it has a result.
fn finished(o: &Order) -> bool {
    o.ended_ms.is_some() && !matches!(o.state, OrderState::Queued | OrderState::Running)
}

/// The order whose result is the latest among `orders`: the one that
/// ended last.
pub fn latest<'a>(orders: &[&'a Order]) -> Option<&'a Order> {
    orders
        .iter()
        .copied()
        .filter(|o| finished(o))
        .max_by_key(|o| (o.ended_ms, o.id))
}

/// The orders a look saw ended, to tell which ended since: the first look
/// only learns them (their results were ready before the gateway was).
#[derive(Debug, Default)]
pub struct Ended {
    seen: Option<BTreeSet<i64>>,
}

impl Ended {
    /// The ids of the orders of `orders` that ended since the last look.
    pub fn update(&mut self, orders: &[&Order]) -> Vec<i64> {
        let now: BTreeSet<i64> = orders
            .iter()
            .filter(|o| finished(o))
            .map(|o| o.id)
            .collect();
        let new = match &self.seen {
            Some(before) => now.difference(before).copied().collect(),
            None => Vec::new(),
        };
        self.seen = Some(now);
        new
    }
}

/// Lays out machine `m`'s ResultManagement with its two methods.
pub fn build(space: &mut AddressSpace, ns: Namespaces, m: &Machine) {
    let own = |id: &str| NodeId::new(ns.own, UAString::from(id));
    let object = own(&m.id(OBJECT));
    ObjectBuilder::new(&object, QualifiedName::new(ns.result, OBJECT), OBJECT)
        .has_type_definition(NodeId::new(
            ns.result,
            ResultObject::ResultManagementType as u32,
        ))
        .reference(
            own(&m.object()),
            ReferenceTypeId::HasAddIn,
            ReferenceDirection::Inverse,
        )
        .insert(space);
    let arg = |name: &str, data_type: NodeId| Argument {
        name: name.into(),
        data_type,
        value_rank: -1,
        array_dimensions: None,
        description: LocalizedText::null(),
    };
    let result = NodeId::new(ns.result, ResultType::ResultDataType as u32);
    for r in ResultMethod::ALL {
        let id_text = r.id(m);
        let timeout = arg("Timeout", DataTypeId::Int32.into());
        let inputs = match r {
            ResultMethod::Latest => vec![timeout],
            ResultMethod::ById => vec![arg("ResultId", DataTypeId::TrimmedString.into()), timeout],
        };
        let outputs = [
            arg("ResultHandle", DataTypeId::Handle.into()),
            arg("Result", result.clone()),
            arg("Error", DataTypeId::Int32.into()),
        ];
        MethodBuilder::new(
            &own(&id_text),
            QualifiedName::new(ns.result, r.name()),
            r.name(),
        )
        .component_of(object.clone())
        .executable(true)
        .user_executable(true)
        .input_args(space, &own(&format!("{id_text}.In")), &inputs)
        .output_args(space, &own(&format!("{id_text}.Out")), &outputs)
        .insert(space);
    }
}

/// A ResultReadyEventType event: the base event's fields and `Result`.
#[derive(Debug)]
pub struct ResultReadyEvent {
    base: opcua::nodes::BaseEventType,
    result_ns: u16,
    result: Variant,
}

impl ResultReadyEvent {
    /// The event of `result` (a ResultDataType, encoded) of the machine
    /// `source` (`name`), Result Transfer's namespace `result_ns`.
    pub fn new(
        result_ns: u16,
        source: NodeId,
        name: &str,
        id: &str,
        result: opcua::types::ExtensionObject,
    ) -> ResultReadyEvent {
        let base = opcua::nodes::BaseEventType::new_now(
            NodeId::new(result_ns, ResultObject::ResultReadyEventType as u32),
            opcua::types::ByteString::from(format!("falc-result-{name}-{id}").into_bytes()),
            LocalizedText::from(format!("result {id} of {name} is ready").as_str()),
        )
        .set_source_node(source)
        .set_source_name(UAString::from(name))
        .set_severity(100);
        ResultReadyEvent {
            base,
            result_ns,
            result: Variant::from(result),
        }
    }
}

impl opcua::nodes::EventField for ResultReadyEvent {
    fn get_value(
        &self,
        attribute_id: AttributeId,
        index_range: &NumericRange,
        browse_path: &[QualifiedName],
    ) -> Variant {
        if self.is_result(browse_path) && attribute_id == AttributeId::Value {
            return self.result.clone();
        }
        self.base.get_value(attribute_id, index_range, browse_path)
    }
}

impl ResultReadyEvent {
    fn is_result(&self, browse_path: &[QualifiedName]) -> bool {
        matches!(browse_path, [name]
            if name.namespace_index == self.result_ns && name.name.as_ref() == "Result")
    }
}

impl opcua::nodes::Event for ResultReadyEvent {
    fn get_field(
        &self,
        type_definition_id: &NodeId,
        attribute_id: AttributeId,
        index_range: &NumericRange,
        browse_path: &[QualifiedName],
    ) -> Variant {
        if self.is_result(browse_path) {
            return opcua::nodes::EventField::get_value(
                self,
                attribute_id,
                index_range,
                browse_path,
            );
        }
        opcua::nodes::Event::get_field(
            &self.base,
            type_definition_id,
            attribute_id,
            index_range,
            browse_path,
        )
    }

    fn time(&self) -> &opcua::types::DateTime {
        opcua::nodes::Event::time(&self.base)
    }

    fn event_type_id(&self) -> &NodeId {
        opcua::nodes::Event::event_type_id(&self.base)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_model::topology::Identification;

    fn order(id: i64, state: OrderState, ended_ms: Option<i64>) -> Order {
        Order {
            id,
            recipe: "dikdroog".into(),
            state,
            added_by: "opcua".into(),
            started_ms: Some(10),
            ended_ms,
            result: ended_ms.map(|_| "done".to_string()),
            cell: Some("falc2".into()),
            wanted: None,
            priority: 0,
            due_ms: None,
            job_order: Some("MES-1".into()),
        }
    }

    #[test]
    fn a_finished_order_is_a_result_and_the_last_one_ended_the_latest() {
        let done = order(1, OrderState::Done, Some(100));
        let failed = order(2, OrderState::Failed, Some(300));
        let running = order(3, OrderState::Running, None);
        let r = of(&done, None).unwrap_or_else(|| panic!("a result"));
        assert_eq!(
            (
                r.id.as_str(),
                r.job.as_deref(),
                r.ok,
                r.ended_ms,
                r.started_ms
            ),
            ("1", Some("MES-1"), true, 100, Some(10))
        );
        assert_eq!(r.details, "order 1 (dikdroog) done: done");
        assert!(!of(&failed, None).is_some_and(|r| r.ok));
        assert_eq!(of(&running, None), None);
        assert_eq!(latest(&[&done, &failed, &running]).map(|o| o.id), Some(2));
        assert_eq!(latest(&[&running]), None);
    }

    #[test]
    fn only_orders_that_end_after_the_first_look_are_ready_results() {
        let mut ended = Ended::default();
        let old = order(1, OrderState::Done, Some(100));
        let mut new = order(2, OrderState::Running, None);
        assert_eq!(ended.update(&[&old, &new]), Vec::<i64>::new());
        assert_eq!(ended.update(&[&old, &new]), Vec::<i64>::new());
        new.state = OrderState::Done;
        new.ended_ms = Some(200);
        assert_eq!(ended.update(&[&old, &new]), vec![2]);
        assert_eq!(ended.update(&[&old, &new]), Vec::<i64>::new());
    }

    #[test]
    fn a_method_node_id_names_its_machine_and_method() {
        let m = Machine {
            name: "falc2".into(),
            identification: Identification::default_for(),
        };
        let id = ResultMethod::Latest.id(&m);
        assert_eq!(id, "Machines.falc2.ResultManagement.GetLatestResult");
        assert_eq!(
            method(&id, [&m].into_iter()).map(|(_, r)| r),
            Some(ResultMethod::Latest)
        );
        assert_eq!(
            method("Machines.falc2.ResultManagement.Nope", [&m].into_iter()),
            None
        );
    }
}
