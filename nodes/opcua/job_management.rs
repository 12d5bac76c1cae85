//! Each machine's JobManagement (OPC 40001-3 Machinery Job Management):
//! its JobOrderControl (an ISA95JobOrderReceiverObjectType of OPC 10031-4,
//! with the job order list and the Store … Abort methods) and its JobOrderResults (an
//! ISA95JobResponseProviderObjectType: the job responses). This module
//! lays them out, gives their values for a look and names the method a
//! node id is; `jobs` decides what a method does and `server` does it.

use crate::jobs::{self, Command, JobState};
use crate::machinery::{Machine, Namespaces};
use crate::space::{Look, Value};
use falc_model::records::Order;
use falc_opcua_models::isa95::ids::{DataTypeId as Isa95Type, ObjectTypeId as Isa95Object};
use falc_opcua_models::jobs::ids::ObjectTypeId as JobsObject;
use opcua::nodes::ReferenceDirection;
use opcua::server::address_space::{AddressSpace, MethodBuilder, ObjectBuilder, VariableBuilder};
use opcua::types::{
    Argument, DataTypeId, LocalizedText, NodeId, QualifiedName, ReferenceTypeId, UAString,
    VariableTypeId, Variant,
};

/// A method of a machine's JobManagement.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JobMethod {
    /// One of JobOrderControl's.
    Control(Command),
    /// JobOrderResults' RequestJobResponseByJobOrderID.
    ResponseById,
    /// JobOrderResults' RequestJobResponseByJobOrderState.
    ResponseByState,
}

const CONTROL: &str = "JobManagement.JobOrderControl";
const RESULTS: &str = "JobManagement.JobOrderResults";

impl JobMethod {
    /// Every method.
    pub fn all() -> impl Iterator<Item = JobMethod> {
        Command::ALL
            .into_iter()
            .map(JobMethod::Control)
            .chain([JobMethod::ResponseById, JobMethod::ResponseByState])
    }

    /// Its browse name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Control(c) => c.name(),
            Self::ResponseById => "RequestJobResponseByJobOrderID",
            Self::ResponseByState => "RequestJobResponseByJobOrderState",
        }
    }

    /// Its node id under machine `m`.
    pub fn id(self, m: &Machine) -> String {
        let object = match self {
            Self::Control(_) => CONTROL,
            Self::ResponseById | Self::ResponseByState => RESULTS,
        };
        m.id(&format!("{object}.{}", self.name()))
    }

    /// Its input and output arguments: name, data type (ISA-95's if
    /// `Some`), value rank.
    fn arguments(self) -> (ArgList, ArgList) {
        let comment = ("Comment", Type::Core(DataTypeId::LocalizedText), 1);
        let status = ("ReturnStatus", Type::Core(DataTypeId::UInt64), -1);
        let id = ("JobOrderID", Type::Core(DataTypeId::String), -1);
        match self {
            Self::Control(c) if c.takes_job_order() => (
                vec![
                    (
                        "JobOrder",
                        Type::Isa95(Isa95Type::ISA95JobOrderDataType),
                        -1,
                    ),
                    comment,
                ],
                vec![status],
            ),
            Self::Control(_) => (vec![id, comment], vec![status]),
            Self::ResponseById => (
                vec![id],
                vec![
                    (
                        "JobResponse",
                        Type::Isa95(Isa95Type::ISA95JobResponseDataType),
                        -1,
                    ),
                    status,
                ],
            ),
            Self::ResponseByState => (
                vec![(
                    "JobOrderState",
                    Type::Isa95(Isa95Type::ISA95StateDataType),
                    1,
                )],
                vec![
                    (
                        "JobResponses",
                        Type::Isa95(Isa95Type::ISA95JobResponseDataType),
                        1,
                    ),
                    status,
                ],
            ),
        }
    }
}

/// An argument's data type.
#[derive(Clone, Copy)]
enum Type {
    Core(DataTypeId),
    Isa95(Isa95Type),
}

type ArgList = Vec<(&'static str, Type, i32)>;

/// The machine and method that node id `id` (of the gateway's namespace)
/// is, among `machines`.
pub fn method<'a>(
    id: &str,
    machines: impl Iterator<Item = &'a Machine>,
) -> Option<(&'a Machine, JobMethod)> {
    machines
        .into_iter()
        .find_map(|m| JobMethod::all().find(|j| j.id(m) == id).map(|j| (m, j)))
}

/// The job orders of machine `m` for this look, whose orders are
/// `orders`: JobOrderControl's list (but those cleared) and
/// JobOrderResults' responses (of the job orders that started).
pub fn values(m: &Machine, look: &Look, orders: &[&Order], put: &mut dyn FnMut(String, Value)) {
    let (list, mode) = look
        .status
        .as_ref()
        .map(|s| (s.list, s.mode))
        .unwrap_or_default();
    let jobs: Vec<jobs::Job> = jobs::jobs(orders, list, mode)
        .into_iter()
        .filter(|j| !look.cleared_jobs.contains(&j.id))
        .collect();
    let started: Vec<jobs::Job> = jobs
        .iter()
        .filter(|j| {
            !matches!(
                j.state,
                JobState::NotAllowedToStart | JobState::AllowedToStart
            )
        })
        .cloned()
        .collect();
    put(
        m.id(&format!("{CONTROL}.JobOrderList")),
        Value::JobOrders(jobs),
    );
    put(
        m.id(&format!("{RESULTS}.JobOrderResponseList")),
        Value::JobResponses(started),
    );
}

/// Lays out machine `m`'s JobManagement: its JobOrderControl and its
/// JobOrderResults.
pub fn build(space: &mut AddressSpace, ns: Namespaces, m: &Machine) {
    let own = |id: &str| NodeId::new(ns.own, UAString::from(id));
    let isa95 = |t: Isa95Type| NodeId::new(ns.isa95, t as u32);
    let management = own(&m.id("JobManagement"));
    ObjectBuilder::new(
        &management,
        QualifiedName::new(ns.jobs, "JobManagement"),
        "JobManagement",
    )
    .has_type_definition(NodeId::new(ns.jobs, JobsObject::JobManagementType as u32))
    .reference(
        own(&m.object()),
        ReferenceTypeId::HasAddIn,
        ReferenceDirection::Inverse,
    )
    .insert(space);
    for (name, t) in [
        (
            "JobOrderControl",
            Isa95Object::ISA95JobOrderReceiverObjectType,
        ),
        (
            "JobOrderResults",
            Isa95Object::ISA95JobResponseProviderObjectType,
        ),
    ] {
        ObjectBuilder::new(
            &own(&m.id(&format!("JobManagement.{name}"))),
            QualifiedName::new(ns.jobs, name),
            name,
        )
        .has_type_definition(NodeId::new(ns.isa95, t as u32))
        .component_of(management.clone())
        .insert(space);
    }
    let control = own(&m.id(CONTROL));
    let results = own(&m.id(RESULTS));
    let lists = [
        (
            &control,
            "JobOrderList",
            Isa95Type::ISA95JobOrderAndStateDataType,
        ),
        (&control, "WorkMaster", Isa95Type::ISA95WorkMasterDataType),
        (
            &results,
            "JobOrderResponseList",
            Isa95Type::ISA95JobResponseDataType,
        ),
    ];
    for (parent, name, t) in lists {
        let object = if parent == &control { CONTROL } else { RESULTS };
        VariableBuilder::new(
            &own(&m.id(&format!("{object}.{name}"))),
            QualifiedName::new(ns.isa95, name),
            name,
        )
        .data_type(isa95(t))
        .value_rank(1)
        .array_dimensions(&[0])
        .value(Variant::from(Vec::<opcua::types::ExtensionObject>::new()))
        .has_type_definition(VariableTypeId::BaseDataVariableType)
        .component_of(parent.clone())
        .insert(space);
    }
    VariableBuilder::new(
        &own(&m.id(&format!("{CONTROL}.EquipmentID"))),
        QualifiedName::new(ns.isa95, "EquipmentID"),
        "EquipmentID",
    )
    .data_type(DataTypeId::String)
    .value_rank(1)
    .array_dimensions(&[0])
    .value(Variant::from(vec![UAString::from(m.name.as_str())]))
    .has_type_definition(VariableTypeId::BaseDataVariableType)
    .component_of(control.clone())
    .insert(space);
    VariableBuilder::new(
        &own(&m.id(&format!("{CONTROL}.MaxDownloadableJobOrders"))),
        QualifiedName::new(ns.isa95, "MaxDownloadableJobOrders"),
        "MaxDownloadableJobOrders",
    )
    .data_type(DataTypeId::UInt16)
    .value(falc_model::api::MAX_ORDERS_PER_ADD)
    .has_type_definition(VariableTypeId::PropertyType)
    .property_of(control.clone())
    .insert(space);
    for j in JobMethod::all() {
        let id_text = j.id(m);
        let id = own(&id_text);
        let parent = match j {
            JobMethod::Control(_) => &control,
            _ => &results,
        };
        let (inputs, outputs) = j.arguments();
        let args = |list: ArgList| -> Vec<Argument> {
            list.into_iter()
                .map(|(name, t, rank)| Argument {
                    name: name.into(),
                    data_type: match t {
                        Type::Core(t) => t.into(),
                        Type::Isa95(t) => isa95(t),
                    },
                    value_rank: rank,
                    array_dimensions: (rank == 1).then(|| vec![0]),
                    description: LocalizedText::null(),
                })
                .collect()
        };
        MethodBuilder::new(&id, QualifiedName::new(ns.isa95, j.name()), j.name())
            .component_of(parent.clone())
            .executable(true)
            .user_executable(true)
            .input_args(space, &own(&format!("{id_text}.In")), &args(inputs))
            .output_args(space, &own(&format!("{id_text}.Out")), &args(outputs))
            .insert(space);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_model::topology::Identification;

    #[test]
    fn a_method_node_id_names_its_machine_and_method() {
        let machines = [
            Machine {
                name: "falc1".into(),
                identification: Identification::default_for(),
            },
            Machine {
                name: "falc2".into(),
                identification: Identification::default_for(),
            },
        ];
        let id = JobMethod::Control(Command::StoreAndStart).id(&machines[1]);
        assert_eq!(
            id,
            "Machines.falc2.JobManagement.JobOrderControl.StoreAndStart"
        );
        let (m, j) = method(&id, machines.iter()).unwrap_or_else(|| panic!("{id} not found"));
        assert_eq!(
            (m.name.as_str(), j),
            ("falc2", JobMethod::Control(Command::StoreAndStart))
        );
        assert_eq!(
            method(&JobMethod::ResponseById.id(&machines[0]), machines.iter())
                .map(|(m, j)| (m.name.as_str(), j)),
            Some(("falc1", JobMethod::ResponseById))
        );
        assert!(method(
            "Machines.falc3.JobManagement.JobOrderControl.Start",
            machines.iter()
        )
        .is_none());
        assert_eq!(JobMethod::all().count(), 13);
    }
}
