//! The gateway's Alarms & Conditions on the wire: each condition state of
//! `conditions` sent as an `AlarmConditionType` event, and the standard
//! methods a client calls on conditions answered by a node manager of the
//! gateway's own, placed before async-opcua's core one (async-opcua 0.19
//! has no A&C; its core manager owns the methods' nodes but carries out
//! none of them):
//! - Acknowledge (`i=9111`) on a condition: `falc ack N` for its alarm, in
//!   the calling user's role (an observer is refused);
//! - ConditionRefresh (`i=3875`) and ConditionRefresh2 (`i=3876`): a
//!   RefreshStartEvent, every retained condition's state, a
//!   RefreshEndEvent.
//!
//! Reads of those method nodes are passed on to the core manager, which
//! holds them. async-opcua drops an event select clause its type tree
//! cannot resolve, and it does not know the ConditionId clause (type
//! ConditionType, no browse path, attribute NodeId), which every A&C
//! client asks for: [`ConditionMethods::init`] teaches it that one.

use crate::conditions::{AckRefusal, Condition, Conditions};
use crate::server::NodeManager as FalcNodes;
use crate::space::Method;
use async_trait::async_trait;
use falc_model::alarm::AlarmClass;
use opcua::core_namespace::events::AlarmConditionType;
use opcua::nodes::{BaseEventType, DefaultTypeTree, Event, EventField, NamespaceMap};
use opcua::server::diagnostics::NamespaceMetadata;
use opcua::server::node_manager::{
    MethodCall, NodeManager, NodeManagerCollection, NodeManagersRef, ReadNode, RequestContext,
    ServerContext,
};
use opcua::server::SubscriptionCache;
use opcua::types::{
    AttributeId, ByteString, DateTime, Identifier, LocalizedText, MethodId, NodeClass, NodeId,
    NumericRange, ObjectId, ObjectTypeId, QualifiedName, StatusCode, TimestampsToReturn, UAString,
    Variant,
};
use std::sync::{Arc, Mutex, OnceLock};

/// The name of the node manager.
pub const NAME: &str = "falc-conditions";

/// The methods it answers.
fn answers(id: &NodeId) -> bool {
    [
        MethodId::AcknowledgeableConditionType_Acknowledge,
        MethodId::ConditionType_ConditionRefresh,
        MethodId::ConditionType_ConditionRefresh2,
    ]
    .into_iter()
    .any(|m| *id == NodeId::from(m))
}

/// An `AlarmConditionType` event with its ConditionId (the condition's
/// node id, selected by type ConditionType, no browse path, attribute
/// NodeId).
#[derive(Debug)]
pub struct ConditionEvent {
    event: AlarmConditionType,
    condition: NodeId,
    /// The text of each two-state variable (`ActiveState` …): the
    /// generated event type answers only its `Id`, and a client shows the
    /// text.
    states: Vec<(&'static str, LocalizedText)>,
}

impl ConditionEvent {
    fn state_text(&self, browse_path: &[QualifiedName]) -> Option<Variant> {
        let [name] = browse_path else {
            return None;
        };
        self.states
            .iter()
            .find(|(n, _)| name.namespace_index == 0 && name.name.as_ref() == *n)
            .map(|(_, text)| Variant::from(text.clone()))
    }
}

impl EventField for ConditionEvent {
    fn get_value(
        &self,
        attribute_id: AttributeId,
        index_range: &NumericRange,
        browse_path: &[QualifiedName],
    ) -> Variant {
        if attribute_id == AttributeId::Value {
            if let Some(text) = self.state_text(browse_path) {
                return text;
            }
        }
        self.event.get_value(attribute_id, index_range, browse_path)
    }
}

impl Event for ConditionEvent {
    fn get_field(
        &self,
        type_definition_id: &NodeId,
        attribute_id: AttributeId,
        index_range: &NumericRange,
        browse_path: &[QualifiedName],
    ) -> Variant {
        if browse_path.is_empty()
            && attribute_id == AttributeId::NodeId
            && type_definition_id == &ObjectTypeId::ConditionType
        {
            return Variant::from(self.condition.clone());
        }
        if attribute_id == AttributeId::Value && type_definition_id == &ObjectTypeId::BaseEventType
        {
            if let Some(text) = self.state_text(browse_path) {
                return text;
            }
        }
        self.event
            .get_field(type_definition_id, attribute_id, index_range, browse_path)
    }

    fn time(&self) -> &DateTime {
        self.event.time()
    }

    fn event_type_id(&self) -> &NodeId {
        self.event.event_type_id()
    }
}

/// The OPC UA condition class of an alarm class.
fn condition_class(class: AlarmClass) -> (ObjectTypeId, &'static str) {
    match class {
        AlarmClass::Safety => (ObjectTypeId::SafetyConditionClassType, "Safety"),
        AlarmClass::Communication => (ObjectTypeId::SystemConditionClassType, "System"),
        AlarmClass::Device => (ObjectTypeId::MaintenanceConditionClassType, "Maintenance"),
        AlarmClass::Process | AlarmClass::Warning => {
            (ObjectTypeId::ProcessConditionClassType, "Process")
        }
    }
}

fn two_state(
    s: &mut opcua::core_namespace::events::TwoStateVariableType,
    on: bool,
    (yes, no): (&str, &str),
    at: DateTime,
) {
    s.id = on;
    s.base.value = LocalizedText::from(if on { yes } else { no });
    s.true_state = LocalizedText::from(yes);
    s.false_state = LocalizedText::from(no);
    s.transition_time = at;
}

/// The event saying condition `c`'s state, its ids in namespace `ns`.
pub fn event(ns: u16, c: &Condition) -> ConditionEvent {
    let time = crate::server::time(c.time_ms);
    let mut e = AlarmConditionType::new_event(
        ObjectTypeId::AlarmConditionType.into(),
        ByteString::from(c.event_id().into_bytes()),
        LocalizedText::from(c.message().as_str()),
        &NamespaceMap::new(),
        time,
    );
    {
        let b: &mut BaseEventType = &mut e.base.base.base;
        b.source_node = NodeId::new(ns, UAString::from(c.source.as_str()));
        b.source_name = UAString::from(c.station.as_str());
        b.severity = c.severity;
        b.receive_time = DateTime::now();
    }
    let cond = &mut e.base.base;
    let (class, class_name) = condition_class(c.class);
    cond.condition_class_id = class.into();
    cond.condition_class_name = LocalizedText::from(class_name);
    cond.condition_name = UAString::from(format!("alarm {}", c.alarm));
    cond.retain = c.retain();
    two_state(&mut cond.enabled_state, true, ("Enabled", "Disabled"), time);
    cond.client_user_id = c
        .acked_by
        .as_deref()
        .map_or_else(UAString::null, UAString::from);
    let ack = &mut e.base;
    two_state(
        &mut ack.acked_state,
        c.acked,
        ("Acknowledged", "Unacknowledged"),
        time,
    );
    two_state(&mut ack.enabled_state, true, ("Enabled", "Disabled"), time);
    two_state(&mut e.active_state, c.active, ("Active", "Inactive"), time);
    two_state(&mut e.enabled_state, true, ("Enabled", "Disabled"), time);
    let state = |on: bool, yes: &str, no: &str| LocalizedText::from(if on { yes } else { no });
    ConditionEvent {
        event: e,
        condition: NodeId::new(ns, UAString::from(c.node.as_str())),
        states: vec![
            ("ActiveState", state(c.active, "Active", "Inactive")),
            (
                "AckedState",
                state(c.acked, "Acknowledged", "Unacknowledged"),
            ),
            ("EnabledState", state(true, "Enabled", "Disabled")),
        ],
    }
}

/// Sends condition states to subscribers of the Server object, where A&C
/// clients subscribe. Not on the cell's object: async-opcua keeps one
/// event per publishing interval for an item that asked for queue size 0
/// or 1, so a condition beside each plain alarm event there would push
/// the plain one out for such a client.
pub fn notify(subscriptions: &SubscriptionCache, ns: u16, states: &[Condition]) {
    let server = NodeId::from(ObjectId::Server);
    for c in states {
        let e = event(ns, c);
        subscriptions.notify_events([(&e as &dyn Event, &server)].into_iter());
    }
}

/// The node manager answering Acknowledge and ConditionRefresh.
pub struct ConditionMethods {
    conditions: Arc<Mutex<Conditions>>,
    /// The gateway's own node manager (calls are made through it), set
    /// once the server is built.
    falc: Arc<OnceLock<Arc<FalcNodes>>>,
    managers: NodeManagersRef,
}

impl ConditionMethods {
    /// The manager of `conditions`, calling through `falc` once it is set.
    pub fn new(
        context: &ServerContext,
        conditions: Arc<Mutex<Conditions>>,
        falc: Arc<OnceLock<Arc<FalcNodes>>>,
    ) -> Self {
        Self {
            conditions,
            falc,
            managers: context.node_managers.clone(),
        }
    }

    async fn acknowledge(&self, context: &RequestContext, call: &mut MethodCall) {
        let Identifier::String(node) = &call.object_id().identifier else {
            call.set_status(StatusCode::BadNodeIdUnknown);
            return;
        };
        let node = node.as_ref().to_string();
        let event_id = match call.arguments().first() {
            Some(Variant::ByteString(b)) => b.value.clone().unwrap_or_default(),
            Some(_) => {
                call.set_status(StatusCode::BadTypeMismatch);
                return;
            }
            None => {
                call.set_status(StatusCode::BadArgumentsMissing);
                return;
            }
        };
        let checked = match self.conditions.lock() {
            Ok(c) => c.acknowledge(&node, &event_id),
            Err(_) => Err(AckRefusal::Unknown),
        };
        let (at, alarm) = match checked {
            Ok(found) => found,
            Err(why) => {
                tracing::warn!(
                    user = context.token.0,
                    "OPC UA Acknowledge of {node}: {why:?}"
                );
                call.set_status(match why {
                    AckRefusal::Unknown => StatusCode::BadNodeIdUnknown,
                    AckRefusal::EventId => StatusCode::BadEventIdUnknown,
                    AckRefusal::Acked => StatusCode::BadConditionBranchAlreadyAcked,
                });
                return;
            }
        };
        let Some(falc) = self.falc.get() else {
            call.set_status(StatusCode::BadServerNotConnected);
            return;
        };
        let result = falc
            .inner()
            .call_one(
                &context.token,
                at,
                Method::Acknowledge,
                &[Variant::Int64(alarm)],
            )
            .await;
        match result {
            Ok(_) => {
                call.set_outputs(Vec::new());
                call.set_status(StatusCode::Good);
            }
            Err(code) => call.set_status(code),
        }
    }

    fn refresh(&self, context: &RequestContext, call: &mut MethodCall) {
        let Some(falc) = self.falc.get() else {
            call.set_status(StatusCode::BadServerNotConnected);
            return;
        };
        let ns = falc.inner().namespace_index();
        let retained = self
            .conditions
            .lock()
            .map(|c| c.retained())
            .unwrap_or_default();
        let server = NodeId::from(ObjectId::Server);
        let mark = |kind: ObjectTypeId, what: &str| {
            let e = BaseEventType::new_now(
                kind,
                ByteString::from(format!("falc-{what}-{}", DateTime::now().ticks()).into_bytes()),
                LocalizedText::from(what),
            )
            .set_source_node(server.clone())
            .set_source_name(UAString::from("Server"))
            .set_severity(1);
            context
                .subscriptions
                .notify_events([(&e as &dyn Event, &server)].into_iter());
        };
        mark(ObjectTypeId::RefreshStartEventType, "refresh start");
        notify(&context.subscriptions, ns, &retained);
        mark(ObjectTypeId::RefreshEndEventType, "refresh end");
        tracing::info!(
            user = context.token.0,
            "OPC UA ConditionRefresh: {} retained conditions sent",
            retained.len()
        );
        call.set_outputs(Vec::new());
        call.set_status(StatusCode::Good);
    }
}

#[async_trait]
impl NodeManager for ConditionMethods {
    fn owns_node(&self, id: &NodeId) -> bool {
        answers(id)
    }

    fn name(&self) -> &str {
        NAME
    }

    fn namespaces_for_user(&self, _context: &RequestContext) -> Vec<NamespaceMetadata> {
        Vec::new()
    }

    async fn init(&self, type_tree: &mut DefaultTypeTree, _context: ServerContext) {
        // The ConditionId select clause: an object "property" of
        // ConditionType at the empty browse path, so async-opcua keeps
        // the clause (and asks each event for it).
        let condition_type: NodeId = ObjectTypeId::ConditionType.into();
        type_tree.add_type_property(
            &NodeId::new(0, UAString::from("falc:ConditionId")),
            &condition_type,
            &[],
            NodeClass::Object,
        );
    }

    async fn read(
        &self,
        context: &RequestContext,
        max_age: f64,
        timestamps_to_return: TimestampsToReturn,
        nodes_to_read: &mut [&mut ReadNode],
    ) -> Result<(), StatusCode> {
        // The method nodes are the core manager's.
        let core = self
            .managers
            .iter_node_managers()
            .find(|m| m.name() == "core")
            .ok_or(StatusCode::BadNodeIdUnknown)?;
        core.read(context, max_age, timestamps_to_return, nodes_to_read)
            .await
    }

    async fn call(
        &self,
        context: &RequestContext,
        methods_to_call: &mut [&mut MethodCall],
    ) -> Result<(), StatusCode> {
        for call in methods_to_call.iter_mut() {
            let id = call.method_id().clone();
            if id == NodeId::from(MethodId::AcknowledgeableConditionType_Acknowledge) {
                self.acknowledge(context, call).await;
            } else {
                self.refresh(context, call);
            }
        }
        Ok(())
    }
}
