//! The OPC UA server of the gateway (async-opcua): endpoints and security,
//! the address space laid out by `space`, values written and alarm events
//! raised as the look loop hands them over, and each object's methods
//! (the one cell's, or the plant's and each of its cells') carried out as
//! operator API calls for that cell, in the calling user's role; the
//! alarms' conditions sent (`conditions`, `condition_methods`).

use crate::condition_methods::{self, ConditionMethods};
use crate::conditions::Conditions;
use crate::job_management::{self, JobMethod};
use crate::jobs;
use crate::machinery;
use crate::result_management::{self, ResultMethod, ResultReadyEvent};
use crate::space::{self, Arg, ArgType, Method, Scope, Value};
use crate::structures::{self, Structures};
use crate::users::Users;
use async_trait::async_trait;
use falc_bus::credentials;
use falc_bus::operator_service::{CallError, CALL_LIMIT};
use falc_bus::Bus;
use falc_model::api::{ApiReply, ApiRequest, ListState};
use falc_model::ids::StationName;
use opcua::server::address_space::{
    AddressSpace, EventNotifier, MethodBuilder, NodeType, ObjectBuilder, VariableBuilder,
};
use opcua::server::diagnostics::{DiagnosticsNodeManagerBuilder, NamespaceMetadata};
use opcua::server::node_manager::memory::{
    simple_node_manager_imports, CoreNodeManagerBuilder, InMemoryNodeManager,
    InMemoryNodeManagerBuilder, InMemoryNodeManagerImpl,
};
use opcua::server::node_manager::{MethodCall, RequestContext, ServerContext};
use opcua::server::{Server, ServerBuilder, ServerEndpoint, ServerHandle, SubscriptionCache};
use opcua::sync::RwLock;
use opcua::types::{
    AttributeId, BuildInfo, ByteString, DataTypeId, DataValue, DateTime, ExtensionObject,
    LocalizedText, NodeId, ObjectId, ObjectTypeId, QualifiedName, StatusCode, TimestampsToReturn,
    UAString, VariableTypeId, Variant,
};
use std::os::unix::fs::PermissionsExt;
use std::path::PathBuf;
use std::sync::Arc;
use tokio::sync::Notify;

/// The fastest publishing interval a subscriber may ask for, in ms.
const PUBLISH_MS: u64 = 20;

/// How often the server looks whether a subscription's publishing
/// interval has passed, in ms. async-opcua publishes a subscription on
/// the first look at which a whole interval has passed since its last
/// publication; looking only every interval, a look a little early (the
/// timer's jitter) waits a whole interval more. Looking every 5 ms, a
/// 20 ms subscription publishes every 20–25 ms.
const TICK_MS: u64 = 5;

/// Where and how the server listens.
#[derive(Debug, Clone)]
pub struct Endpoint {
    /// Host name or address to bind and to name in endpoint URLs.
    pub host: String,
    /// TCP port.
    pub port: u16,
    /// The server's own certificate and key, trusted and rejected client
    /// certificates (made on first start).
    pub pki_dir: PathBuf,
    /// Also offer an endpoint without signing or encryption (passwords are
    /// still encrypted with the server's key).
    pub insecure: bool,
}

/// The gateway's node manager: its address space and the methods.
pub struct Nodes {
    namespace: NamespaceMetadata,
    scopes: Vec<Scope>,
    users: Arc<Users>,
    bus: Bus,
    operator: StationName,
    poked: Arc<Notify>,
    last_refusals: LastRefusals,
    /// The namespaces of the cells as machines (None: Machinery's
    /// namespace is missing, and no machine is laid out).
    machinery: Option<machinery::Namespaces>,
    /// ISA-95's structures (None: its namespace is missing).
    structures: Option<Arc<Structures>>,
    /// The JobOrderIDs of the job orders cleared (Clear): no longer
    /// listed (their orders' records stay).
    cleared_jobs: ClearedJobs,
    /// Held while a job order command looks at the job orders and acts,
    /// so that two at once cannot both find a JobOrderID new.
    job_commands: tokio::sync::Mutex<()>,
}

/// The JobOrderIDs of the job orders cleared, shared with the look loop.
pub type ClearedJobs = Arc<std::sync::Mutex<Vec<String>>>;

/// Why the operator refused the last method call on each scope's object
/// (in the order of the scopes).
pub type LastRefusals = Arc<std::sync::Mutex<Vec<String>>>;

/// The node manager as the server holds it.
pub type NodeManager = InMemoryNodeManager<Nodes>;

fn node(ns: u16, id: &str) -> NodeId {
    NodeId::new(ns, UAString::from(id))
}

fn data_type(v: &Value) -> (DataTypeId, i32) {
    match v {
        Value::Bool(_) => (DataTypeId::Boolean, -1),
        Value::Byte(_) => (DataTypeId::Byte, -1),
        Value::Int32(_) => (DataTypeId::Int32, -1),
        Value::Int64(_) => (DataTypeId::Int64, -1),
        Value::Text(_) => (DataTypeId::String, -1),
        Value::Bools(_) => (DataTypeId::Boolean, 1),
        Value::Int64s(_) => (DataTypeId::Int64, 1),
        Value::Texts(_) => (DataTypeId::String, 1),
        Value::Times(_) => (DataTypeId::DateTime, 1),
        Value::Localized(_) => (DataTypeId::LocalizedText, -1),
        Value::StateId(_) => (DataTypeId::NodeId, -1),
        Value::JobOrders(_) | Value::JobResponses(_) => (DataTypeId::Structure, 1),
    }
}

/// A time in ms since the Unix epoch as OPC UA's.
pub fn time(ms: i64) -> DateTime {
    DateTime::from(chrono::DateTime::<chrono::Utc>::from_timestamp_millis(ms).unwrap_or_default())
}

impl Nodes {
    /// The OPC UA value of `v` (a state Id in Machinery's namespace,
    /// job orders as ISA-95's structures).
    pub fn variant(&self, v: &Value) -> Variant {
        match v {
            Value::Bool(b) => Variant::from(*b),
            Value::Byte(b) => Variant::from(*b),
            Value::Int32(n) => Variant::from(*n),
            Value::Int64(n) => Variant::from(*n),
            Value::Text(t) => Variant::from(t.as_str()),
            Value::Bools(v) => Variant::from(v.clone()),
            Value::Int64s(v) => Variant::from(v.clone()),
            Value::Texts(v) => Variant::from(
                v.iter()
                    .map(|t| UAString::from(t.as_str()))
                    .collect::<Vec<_>>(),
            ),
            Value::Times(v) => Variant::from(v.iter().map(|&ms| time(ms)).collect::<Vec<_>>()),
            Value::Localized(t) => Variant::from(LocalizedText::from(t.as_str())),
            Value::StateId(n) => Variant::from(NodeId::new(self.machinery_ns(), *n)),
            Value::JobOrders(jobs) => self.structures_of(jobs, |s, j| s.job_order_and_state(j)),
            Value::JobResponses(jobs) => {
                self.structures_of(jobs, |s, j| s.response(&jobs::response(j, None, &[])))
            }
        }
    }

    /// An array of a structure per job order (empty, and a warning, if
    /// one cannot be made).
    fn structures_of(
        &self,
        jobs: &[jobs::Job],
        make: impl Fn(&Structures, &jobs::Job) -> Result<ExtensionObject, String>,
    ) -> Variant {
        let Some(s) = &self.structures else {
            return Variant::from(Vec::<ExtensionObject>::new());
        };
        match jobs
            .iter()
            .map(|j| make(s, j))
            .collect::<Result<Vec<_>, _>>()
        {
            Ok(all) => Variant::from(all),
            Err(why) => {
                tracing::warn!("OPC UA job orders not served: {why}");
                Variant::from(Vec::<ExtensionObject>::new())
            }
        }
    }

    fn build(&self, ns: u16, space_: &mut AddressSpace) {
        // Browse names in the gateway's namespace (`2:FALC`).
        let qn = |name: &str| QualifiedName::new(ns, name);
        for o in space::layout(&self.scopes) {
            let id = node(ns, &o.id);
            let parent = o
                .parent
                .as_deref()
                .map_or_else(|| NodeId::from(ObjectId::ObjectsFolder), |p| node(ns, p));
            if o.folder {
                space_.add_folder(&id, qn(&o.name), o.name.as_str(), &parent);
            } else {
                let b = ObjectBuilder::new(&id, qn(&o.name), o.name.as_str())
                    .has_type_definition(ObjectTypeId::BaseObjectType);
                // Each cell object (and the plant's) is where its alarm
                // events come from.
                let b = if self.scopes.iter().any(|scope| scope.root == o.id) {
                    b.organized_by(parent)
                        .event_notifier(EventNotifier::SUBSCRIBE_TO_EVENTS)
                } else {
                    b.organized_by(parent)
                };
                b.insert(space_);
            }
        }
        for scope in &self.scopes {
            self.build_scope(ns, scope, space_);
            if let (Some(m), Some(namespaces)) = (&scope.machine, self.machinery) {
                machinery::build(space_, namespaces, m);
                job_management::build(space_, namespaces, m);
                result_management::build(space_, namespaces, m);
            }
        }
    }

    /// One scope's variables and methods.
    fn build_scope(&self, ns: u16, scope: &Scope, space_: &mut AddressSpace) {
        let qn = |name: &str| QualifiedName::new(ns, name);
        for (id, v) in space::values(scope, &space::Look::default()) {
            // A machine's nodes are typed ones of their own (`machinery`).
            if id.starts_with(machinery::MACHINES) {
                continue;
            }
            let (parent, name) = id.rsplit_once('.').unwrap_or((&scope.root, &id));
            let (dt, rank) = data_type(&v);
            let b = VariableBuilder::new(&node(ns, &id), qn(name), name)
                .data_type(dt)
                .value_rank(rank)
                .value(self.variant(&v))
                .has_type_definition(VariableTypeId::BaseDataVariableType)
                .component_of(node(ns, parent));
            let b = if rank == 1 {
                b.array_dimensions(&[0])
            } else {
                b
            };
            b.insert(space_);
        }
        let root = node(ns, &scope.root);
        for m in Method::ALL {
            let id_text = scope.method_id(m);
            let id = node(ns, &id_text);
            let mut b = MethodBuilder::new(&id, qn(m.name()), m.name())
                .component_of(root.clone())
                .executable(true)
                .user_executable(true);
            let inputs: Vec<_> = m
                .inputs()
                .iter()
                .map(|(name, t)| {
                    let dt = match t {
                        ArgType::Text => DataTypeId::String,
                        ArgType::Int64 => DataTypeId::Int64,
                    };
                    (*name, dt).into()
                })
                .collect();
            if !inputs.is_empty() {
                b = b.input_args(space_, &node(ns, &format!("{id_text}.In")), &inputs);
            }
            b = b.output_args(
                space_,
                &node(ns, &format!("{id_text}.Out")),
                &[("Result", DataTypeId::String).into()],
            );
            b.insert(space_);
        }
    }

    /// Its namespace's index.
    pub fn namespace_index(&self) -> u16 {
        self.namespace.namespace_index
    }

    /// The index of OPC UA Machinery's namespace (0 while it is missing:
    /// no machine is laid out then).
    fn machinery_ns(&self) -> u16 {
        self.machinery.map_or(0, |n| n.machinery)
    }

    /// Carries out one method call on scope `at`'s object as `token`'s
    /// user: the answer in words, or the status code that refuses it.
    pub async fn call_one(
        &self,
        token: &opcua::server::authenticator::UserToken,
        at: usize,
        method: Method,
        args: &[Variant],
    ) -> Result<String, StatusCode> {
        let Some(scope) = self.scopes.get(at) else {
            return Err(StatusCode::BadMethodInvalid);
        };
        let what = scope.method_id(method);
        if let Err(why) = self.users.may(token, method.call()) {
            tracing::warn!("OPC UA {what}: {why}");
            // Every refusal is the last one, this one too.
            self.refused(at, why.to_string());
            return Err(StatusCode::BadUserAccessDenied);
        }
        let args: Vec<Arg> = args
            .iter()
            .map(|a| match a {
                Variant::String(s) => Arg::Text(s.as_ref().to_string()),
                Variant::Int64(n) => Arg::Int64(*n),
                Variant::Int32(n) => Arg::Int64(i64::from(*n)),
                Variant::UInt32(n) => Arg::Int64(i64::from(*n)),
                Variant::Int16(n) => Arg::Int64(i64::from(*n)),
                Variant::UInt16(n) => Arg::Int64(i64::from(*n)),
                other => Arg::Other(format!("{:?}", other.type_id())),
            })
            .collect();
        let request = scope.request(method, &args).map_err(|why| {
            tracing::warn!("OPC UA {what}: {why}");
            self.refused(at, why);
            StatusCode::BadInvalidArgument
        })?;
        tracing::info!(user = token.0, "OPC UA {what}: {request:?}");
        // A cell's object calls for its cell, as `falc --cell` does.
        let result = self
            .bus
            .clone()
            .for_cell(scope.cell().cloned())
            .api(&self.operator, request.clone(), CALL_LIMIT)
            .await;
        self.poked.notify_one();
        match result {
            Ok(ApiReply::Order(o)) => Ok(o.id.to_string()),
            Ok(ApiReply::Done(text)) => Ok(text),
            Ok(other) => Ok(format!("{other:?}")),
            Err(CallError::Refused(why)) => {
                tracing::warn!(user = token.0, "OPC UA {what}: refused: {why}");
                self.refused(at, why);
                Err(match request {
                    ApiRequest::OrderAdd { .. } | ApiRequest::OrderRemove { .. } => {
                        StatusCode::BadInvalidArgument
                    }
                    _ => StatusCode::BadInvalidState,
                })
            }
            Err(CallError::NoReply(why)) => {
                tracing::warn!("OPC UA {what}: {why}");
                self.refused(at, why);
                Err(StatusCode::BadCommunicationError)
            }
        }
    }

    /// The scope whose machine is `m`.
    fn scope_of(&self, m: &machinery::Machine) -> Option<usize> {
        self.scopes
            .iter()
            .position(|s| s.machine.as_ref() == Some(m))
    }

    /// The method of a machine that node `id` is (`find`: which, among
    /// the machines), and its scope.
    fn machine_method<'a, T>(
        &'a self,
        id: &NodeId,
        find: impl FnOnce(
            &str,
            &mut dyn Iterator<Item = &'a machinery::Machine>,
        ) -> Option<(&'a machinery::Machine, T)>,
    ) -> Option<(usize, T)> {
        if id.namespace != self.namespace_index() {
            return None;
        }
        let opcua::types::Identifier::String(text) = &id.identifier else {
            return None;
        };
        let mut machines = self.scopes.iter().filter_map(|s| s.machine.as_ref());
        let (m, t) = find(text.as_ref(), &mut machines)?;
        Some((self.scope_of(m)?, t))
    }

    /// The JobManagement method node `id` is, and its scope.
    fn job_method(&self, id: &NodeId) -> Option<(usize, JobMethod)> {
        self.machine_method(id, |text, machines| job_management::method(text, machines))
    }

    /// The ResultManagement method node `id` is, and its scope.
    fn result_method(&self, id: &NodeId) -> Option<(usize, ResultMethod)> {
        self.machine_method(id, |text, machines| {
            result_management::method(text, machines)
        })
    }

    /// Answers ResultManagement method `r` of scope `at`'s machine as
    /// `token`'s user: ResultHandle (0: FALC keeps every result), the
    /// result and Error (0, or [`result_management::NO_RESULT`] /
    /// [`result_management::NOT_ENDED`] with an empty result).
    async fn call_result(
        &self,
        token: &opcua::server::authenticator::UserToken,
        at: usize,
        r: ResultMethod,
        args: &[Variant],
    ) -> (StatusCode, Vec<Variant>) {
        let what = format!("{}.{}", self.scopes[at].root, r.name());
        if let Err(why) = self.users.may(token, falc_model::api::Call::OrderShow) {
            tracing::warn!("OPC UA {what}: {why}");
            self.refused(at, why);
            return (StatusCode::BadUserAccessDenied, Vec::new());
        }
        let answer = |error: i32, result: ExtensionObject| {
            vec![Variant::from(0u32), result.into(), Variant::from(error)]
        };
        let Some(structures) = self.structures.clone() else {
            return (StatusCode::BadNotSupported, Vec::new());
        };
        let orders = match self.orders_now().await {
            Ok(orders) => orders,
            Err(why) => {
                tracing::warn!("OPC UA {what}: {why}");
                return (StatusCode::BadCommunicationError, Vec::new());
            }
        };
        let mine = space::cell_orders(self.scopes[at].cell(), &orders);
        let order = match r {
            ResultMethod::Latest => result_management::latest(&mine),
            ResultMethod::ById => match args.first() {
                Some(Variant::String(id)) => mine
                    .iter()
                    .copied()
                    .find(|o| Some(o.id.to_string().as_str()) == id.value().as_deref()),
                _ => None,
            },
        };
        let Some(order) = order else {
            return (
                StatusCode::Good,
                answer(result_management::NO_RESULT, ExtensionObject::null()),
            );
        };
        let record = match self.ask(at, ApiRequest::OrderShow { id: order.id }).await {
            Ok(ApiReply::OrderRecord(r)) => Some(*r),
            _ => None,
        };
        let Some(result) = result_management::of(order, record.as_ref()) else {
            return (
                StatusCode::Good,
                answer(result_management::NOT_ENDED, ExtensionObject::null()),
            );
        };
        match structures.result(&result) {
            Ok(o) => (StatusCode::Good, answer(result_management::OK, o)),
            Err(why) => {
                tracing::warn!("OPC UA {what}: {why}");
                (StatusCode::BadInternalError, Vec::new())
            }
        }
    }

    /// The ResultReadyEvent of `result` of scope `at`'s machine (None:
    /// no machine, or Result Transfer's types are missing).
    pub fn result_ready(
        &self,
        at: usize,
        result: &result_management::MachineResult,
    ) -> Option<ResultReadyEvent> {
        let (ns, m) = (self.machinery?, self.scopes.get(at)?.machine.as_ref()?);
        let encoded = match self.structures.as_ref()?.result(result) {
            Ok(o) => o,
            Err(why) => {
                tracing::warn!("OPC UA result {} not sent: {why}", result.id);
                return None;
            }
        };
        let source = NodeId::new(ns.own, UAString::from(m.object()));
        Some(ResultReadyEvent::new(
            ns.result, source, &m.name, &result.id, encoded,
        ))
    }

    /// Asks the operator `request` for scope `at`'s cell.
    async fn ask(&self, at: usize, request: ApiRequest) -> Result<ApiReply, CallError> {
        let cell = self.scopes.get(at).and_then(|s| s.cell().cloned());
        self.bus
            .clone()
            .for_cell(cell)
            .api(&self.operator, request, CALL_LIMIT)
            .await
    }

    /// Scope `at`'s job orders now, with its list's state.
    async fn jobs_now(&self, at: usize) -> Result<(Vec<jobs::Job>, ListState), String> {
        let scope = &self.scopes[at];
        // The whole plant's status and order list, as the look loop asks.
        let status = self
            .bus
            .api(&self.operator, ApiRequest::Status, CALL_LIMIT)
            .await
            .map_err(|e| e.to_string())?;
        let status = space::status_of(scope, Some(&status))
            .ok_or_else(|| format!("no status of {}", scope.root))?;
        let orders = self.orders_now().await?;
        let mine = space::cell_orders(scope.cell(), &orders);
        Ok((jobs::jobs(&mine, status.list, status.mode), status.list))
    }

    /// The whole order list now (each scope takes its cell's).
    async fn orders_now(&self) -> Result<Vec<falc_model::records::Order>, String> {
        match self
            .bus
            .api(&self.operator, ApiRequest::OrderList, CALL_LIMIT)
            .await
        {
            Ok(ApiReply::Orders(orders)) => Ok(orders),
            Ok(other) => Err(format!(
                "the operator answered {other:?}, not the order list"
            )),
            Err(e) => Err(e.to_string()),
        }
    }

    /// A job command or request FALC refuses: Uncertain, with ReturnStatus
    /// `bits`, and `why` in a warning and in `LastRefusal`.
    fn refuse_job(
        &self,
        token: &opcua::server::authenticator::UserToken,
        at: usize,
        what: &str,
        bits: u64,
        why: String,
    ) -> (StatusCode, u64) {
        tracing::warn!(user = token.0, "OPC UA {what}: {why}");
        self.refused(at, why);
        (StatusCode::Uncertain, bits)
    }

    /// Carries out JobManagement method `j` of scope `at`'s machine as
    /// `token`'s user: its status code and outputs. A command FALC
    /// refuses is Uncertain, its ReturnStatus saying why in bits and
    /// `LastRefusal` in words (OPC 10031-4 B.2).
    async fn call_job(
        &self,
        token: &opcua::server::authenticator::UserToken,
        at: usize,
        j: JobMethod,
        args: &[Variant],
    ) -> (StatusCode, Vec<Variant>) {
        let Some(structures) = self.structures.clone() else {
            return (StatusCode::BadNotSupported, Vec::new());
        };
        let scope = &self.scopes[at];
        let what = format!("{}.{}", scope.root, j.name());
        let refuse = |bits: u64, why: String| self.refuse_job(token, at, &what, bits, why);
        // Reading job responses is an observer's; commands an operator's.
        let needs = match j {
            JobMethod::Control(_) => falc_model::api::Call::OrderAdd,
            _ => falc_model::api::Call::OrderShow,
        };
        if let Err(why) = self.users.may(token, needs) {
            tracing::warn!("OPC UA {what}: {why}");
            self.refused(at, why);
            return (StatusCode::BadUserAccessDenied, Vec::new());
        }
        // Commands one at a time, from the look at the job orders to the
        // last call (requests for responses need no turn).
        let _turn = match j {
            JobMethod::Control(_) => Some(self.job_commands.lock().await),
            _ => None,
        };
        let (jobs_now, list) = match self.jobs_now(at).await {
            Ok(j) => j,
            Err(why) => {
                tracing::warn!("OPC UA {what}: {why}");
                self.refused(at, why);
                return (StatusCode::BadCommunicationError, Vec::new());
            }
        };
        match j {
            JobMethod::Control(command) => {
                let (code, bits) = self
                    .command(token, at, command, args, &jobs_now, list, &structures)
                    .await;
                (code, vec![Variant::from(bits)])
            }
            JobMethod::ResponseById => {
                let job = args
                    .first()
                    .map(structures::job_order_id)
                    .transpose()
                    .ok()
                    .flatten()
                    .and_then(|id| jobs_now.into_iter().find(|j| j.id == id));
                let Some(job) = job else {
                    let (code, bits) =
                        refuse(jobs::status::UNKNOWN_JOB_ORDER, "no such job order".into());
                    return (code, vec![ExtensionObject::null().into(), bits.into()]);
                };
                let response = self.response(at, &job, &structures).await;
                match response {
                    Ok(r) => (
                        StatusCode::Good,
                        vec![r.into(), Variant::from(jobs::status::NO_ERROR)],
                    ),
                    Err(why) => {
                        let (code, bits) = refuse(jobs::status::INVALID_REQUEST, why);
                        (code, vec![ExtensionObject::null().into(), bits.into()])
                    }
                }
            }
            JobMethod::ResponseByState => {
                let wanted: Vec<u32> = match args.first() {
                    Some(Variant::Array(a)) => a
                        .values
                        .iter()
                        .filter_map(structures::state_number)
                        .collect(),
                    _ => Vec::new(),
                };
                let mut out = Vec::new();
                for job in jobs_now
                    .iter()
                    .filter(|j| wanted.contains(&j.state.number()))
                {
                    match self.response(at, job, &structures).await {
                        Ok(r) => out.push(r),
                        Err(why) => {
                            let (code, bits) = refuse(jobs::status::INVALID_REQUEST, why);
                            return (code, vec![Variant::from(out), bits.into()]);
                        }
                    }
                }
                (
                    StatusCode::Good,
                    vec![Variant::from(out), Variant::from(jobs::status::NO_ERROR)],
                )
            }
        }
    }

    /// One of JobOrderControl's commands: checked, planned (`jobs::plan`)
    /// and carried out call by call.
    #[allow(clippy::too_many_arguments)]
    async fn command(
        &self,
        token: &opcua::server::authenticator::UserToken,
        at: usize,
        command: jobs::Command,
        args: &[Variant],
        jobs_now: &[jobs::Job],
        list: ListState,
        structures: &Structures,
    ) -> (StatusCode, u64) {
        use jobs::status::*;
        let scope = &self.scopes[at];
        let what = format!("{}.{}", scope.root, command.name());
        let refuse = |bits: u64, why: String| self.refuse_job(token, at, &what, bits, why);
        let cell = scope.cell();
        let first = args.first().unwrap_or(&Variant::Empty);
        let (order, id) = if command.takes_job_order() {
            match structures::job_order(first, structures.isa95())
                .and_then(|j| jobs::JobOrder::check(&j, cell))
            {
                Ok(o) => {
                    let id = o.id.clone();
                    (Some(o), id)
                }
                Err(why) => return refuse(UNABLE_TO_ACCEPT, why),
            }
        } else {
            match structures::job_order_id(first) {
                Ok(id) => (None, id),
                Err(why) => return refuse(INVALID_REQUEST, why),
            }
        };
        let calls = match jobs::plan(command, order.as_ref(), &id, cell, jobs_now, list) {
            Ok(calls) => calls,
            Err((bits, why)) => return refuse(bits, why),
        };
        for call in &calls {
            if let Err(why) = self.users.may(token, call.call()) {
                tracing::warn!("OPC UA {}: {why}", command.name());
                self.refused(at, why);
                return (StatusCode::BadUserAccessDenied, INVALID_REQUEST);
            }
        }
        tracing::info!(
            user = token.0,
            "OPC UA job order {id}: {} = {calls:?}",
            command.name()
        );
        for call in calls {
            let bits = jobs::refused_status(&call);
            let result = self.ask(at, call).await;
            self.poked.notify_one();
            if let Err(e) = result {
                return refuse(bits, format!("job order {id}: {e}"));
            }
        }
        if command == jobs::Command::Clear {
            if let Ok(mut c) = self.cleared_jobs.lock() {
                c.push(id);
            }
            self.poked.notify_one();
        }
        (StatusCode::Good, NO_ERROR)
    }

    /// The job response of `job` on scope `at`'s machine, with its
    /// orders' records.
    async fn response(
        &self,
        at: usize,
        job: &jobs::Job,
        structures: &Structures,
    ) -> Result<ExtensionObject, String> {
        let mut records = Vec::new();
        for &id in &job.orders {
            match self.ask(at, ApiRequest::OrderShow { id }).await {
                Ok(ApiReply::OrderRecord(r)) => records.push(*r),
                Ok(other) => return Err(format!("order {id}: the operator answered {other:?}")),
                Err(e) => return Err(format!("order {id}: {e}")),
            }
        }
        let cell = self.scopes[at].cell();
        structures.response(&jobs::response(job, cell, &records))
    }

    fn refused(&self, at: usize, why: String) {
        if let Ok(mut last) = self.last_refusals.lock() {
            if let Some(slot) = last.get_mut(at) {
                *slot = why;
            }
        }
        self.poked.notify_one();
    }

    /// The object and method of method node `id`.
    fn method(&self, id: &NodeId) -> Option<(usize, Method)> {
        self.scopes
            .iter()
            .enumerate()
            .find_map(|(at, scope)| Some((at, scope.method(id)?)))
    }
}

impl Nodes {
    /// Writes scope `at`'s `LastRefusal` before the method returns, so a
    /// client reading it at once reads this refusal's words.
    fn write_refusal(&self, context: &RequestContext, space_: &RwLock<AddressSpace>, at: usize) {
        let why = self
            .last_refusals
            .lock()
            .ok()
            .and_then(|w| w.get(at).cloned())
            .unwrap_or_default();
        let id = self.scopes[at].id("LastRefusal");
        if !write_values(
            space_,
            &context.subscriptions,
            self,
            &[(id, Value::Text(why))],
        ) {
            tracing::warn!("OPC UA: LastRefusal not written");
        }
    }
}

#[async_trait]
impl InMemoryNodeManagerImpl for Nodes {
    async fn init(&self, space_: &mut AddressSpace, _context: ServerContext) {
        self.build(self.namespace.namespace_index, space_);
    }

    fn name(&self) -> &str {
        "falc"
    }

    fn namespaces(&self) -> Vec<NamespaceMetadata> {
        vec![self.namespace.clone()]
    }

    async fn call(
        &self,
        context: &RequestContext,
        space_: &RwLock<AddressSpace>,
        methods: &mut [&mut &mut MethodCall],
    ) -> Result<(), StatusCode> {
        for call in methods {
            if let Some((at, r)) = self.result_method(call.method_id()) {
                let args = call.arguments().to_vec();
                let (code, outputs) = self.call_result(&context.token, at, r, &args).await;
                self.write_refusal(context, space_, at);
                if !outputs.is_empty() {
                    call.set_outputs(outputs);
                }
                call.set_status(code);
                continue;
            }
            if let Some((at, j)) = self.job_method(call.method_id()) {
                let args = call.arguments().to_vec();
                let (code, outputs) = self.call_job(&context.token, at, j, &args).await;
                self.write_refusal(context, space_, at);
                if !outputs.is_empty() {
                    call.set_outputs(outputs);
                }
                call.set_status(code);
                continue;
            }
            let Some((at, m)) = self.method(call.method_id()) else {
                call.set_status(StatusCode::BadMethodInvalid);
                continue;
            };
            let args = call.arguments().to_vec();
            let result = self.call_one(&context.token, at, m, &args).await;
            if result.is_err() {
                self.write_refusal(context, space_, at);
            }
            match result {
                Ok(text) => {
                    call.set_outputs(vec![Variant::from(text.as_str())]);
                    call.set_status(StatusCode::Good);
                }
                Err(code) => call.set_status(code),
            }
        }
        Ok(())
    }
}

/// Writes values of `nodes`' namespace into the address space and
/// notifies their subscribers: the look loop's changes, and a method's
/// refusal before the method returns. False if a node is missing or not a
/// variable (nothing after it is written).
fn write_values(
    space_: &RwLock<AddressSpace>,
    subscriptions: &SubscriptionCache,
    nodes: &Nodes,
    changes: &[(String, Value)],
) -> bool {
    let ns = nodes.namespace_index();
    let now = DateTime::now();
    let mut space_ = space_.write();
    let mut written = Vec::new();
    for (id, value) in changes {
        let id = node(ns, id);
        match space_.find_mut(&id) {
            Some(NodeType::Variable(v)) => {
                v.set_data_value(DataValue {
                    value: Some(nodes.variant(value)),
                    status: Some(StatusCode::Good),
                    source_timestamp: Some(now),
                    server_timestamp: Some(now),
                    ..DataValue::null()
                });
                written.push((id, AttributeId::Value));
            }
            _ => {
                tracing::warn!("OPC UA value not set: no variable {id}");
                return false;
            }
        }
    }
    subscriptions.maybe_notify(
        written.iter().map(|(id, a)| (id, *a)),
        |id, attribute, range, encoding| {
            space_.find(id)?.as_node().get_attribute(
                TimestampsToReturn::Both,
                attribute,
                range,
                encoding,
            )
        },
    );
    true
}

/// What the poll loop needs of the running server.
pub struct Running {
    /// Stops the server.
    pub handle: ServerHandle,
    /// The node manager (values are set through it).
    pub nodes: Arc<NodeManager>,
    /// Our namespace's index.
    pub ns: u16,
    /// Notified after each method call, so its effect shows at once.
    pub poked: Arc<Notify>,
    /// The operator's refusal of the last method call on each object.
    pub last_refusals: LastRefusals,
    /// The alarms' conditions.
    pub conditions: Arc<std::sync::Mutex<Conditions>>,
    /// The job orders cleared.
    pub cleared_jobs: ClearedJobs,
}

impl Running {
    fn subscriptions(&self) -> &Arc<SubscriptionCache> {
        self.handle.subscriptions()
    }

    /// Whether the server has laid out the address space (it does so once
    /// it runs).
    pub fn laid_out(&self) -> bool {
        self.nodes
            .address_space()
            .read()
            .find(&node(self.ns, space::ROOT))
            .is_some()
    }

    /// Writes changed values; subscribers are notified. False if they
    /// could not be written (then all are written again next time).
    pub fn set(&self, changes: &[(String, Value)]) -> bool {
        write_values(
            self.nodes.address_space(),
            self.subscriptions(),
            self.nodes.inner(),
            changes,
        )
    }

    /// Scope `at`'s alarm list as the operator gave it: the conditions
    /// that changed are sent to their subscribers.
    pub fn conditions(&self, at: usize, scope: &Scope, alarms: &[falc_model::alarm::Alarm]) {
        let changed = match self.conditions.lock() {
            Ok(mut c) => c.update(at, scope, alarms, falc_node::now_ms()),
            Err(_) => return,
        };
        condition_methods::notify(self.subscriptions(), self.ns, &changed);
    }

    /// Sends the ResultReadyEvent of scope `at`'s `result` on the Server
    /// object.
    pub fn result_ready(&self, at: usize, result: &result_management::MachineResult) {
        if let Some(e) = self.nodes.inner().result_ready(at, result) {
            tracing::info!("OPC UA result {} ready: {}", result.id, result.details);
            let server = NodeId::from(ObjectId::Server);
            self.subscriptions()
                .notify_events([(&e as &dyn opcua::nodes::Event, &server)].into_iter());
        }
    }

    /// Raises alarm events on the cell object `root` (and the Server
    /// object, where clients listening to everything subscribe).
    pub fn raise(&self, root: &str, events: &[space::AlarmEvent]) {
        let root = node(self.ns, root);
        let server = NodeId::from(ObjectId::Server);
        let made: Vec<_> = events
            .iter()
            .map(|e| {
                let id =
                    ByteString::from(format!("falc-alarm-{}-{}", e.id, e.message).into_bytes());
                opcua::nodes::BaseEventType::new_now(
                    ObjectTypeId::BaseEventType,
                    id,
                    LocalizedText::from(e.message.as_str()),
                )
                .set_source_node(root.clone())
                .set_source_name(UAString::from(e.station.as_str()))
                .set_severity(e.severity)
            })
            .collect();
        for e in &made {
            for emitter in [&root, &server] {
                self.subscriptions()
                    .notify_events([(e as &dyn opcua::nodes::Event, emitter)].into_iter());
            }
        }
    }
}

/// Builds the server of cell or plant `name` (`what`: "cell", "plant"):
/// endpoints, users, the node manager serving `scopes`.
pub fn build(
    endpoint: &Endpoint,
    (what, name): (&str, &str),
    scopes: Vec<Scope>,
    users: Arc<Users>,
    bus: Bus,
    operator: StationName,
) -> Result<(Server, Running), String> {
    let uri = format!("urn:falc:{name}");
    let poked = Arc::new(Notify::new());
    let last_refusals = Arc::new(std::sync::Mutex::new(vec![String::new(); scopes.len()]));
    let (poked2, refusal2) = (poked.clone(), last_refusals.clone());
    let cleared_jobs = ClearedJobs::default();
    let cleared2 = cleared_jobs.clone();
    let users2 = users.clone();
    let namespace_uri = uri.clone();
    let manager = InMemoryNodeManagerBuilder::new(
        move |context: ServerContext, space_: &mut AddressSpace| {
            let index = context
                .type_tree
                .write()
                .namespaces_mut()
                .add_namespace(&namespace_uri);
            space_.add_namespace(&namespace_uri, index);
            // The companion specifications' namespaces, registered by
            // their node manager (before this one).
            let machinery = {
                let tree = context.type_tree.read();
                let of = |uri: &str| tree.namespaces().get_index(uri);
                match (
                    of(falc_opcua_models::di::URI),
                    of(falc_opcua_models::machinery::URI),
                    of(falc_opcua_models::isa95::URI),
                    of(falc_opcua_models::jobs::URI),
                    of(falc_opcua_models::result::URI),
                ) {
                    (Some(di), Some(m), Some(isa95), Some(jobs), Some(result)) => {
                        Some(machinery::Namespaces {
                            own: index,
                            di,
                            machinery: m,
                            isa95,
                            jobs,
                            result,
                        })
                    }
                    _ => None,
                }
            };
            if machinery.is_none() {
                tracing::warn!("OPC UA Machinery's namespaces are missing: no machine is laid out");
            }
            // ISA-95's structures, decoded in requests and encoded in
            // values from their definitions (`structures`).
            let structures = Structures::load(
                context.type_tree.read().namespaces(),
                &[
                    &opcua::server::address_space::CoreNamespace,
                    &falc_opcua_models::isa95::Isa95JobControlNamespace,
                    &falc_opcua_models::result::MachineryResultNamespace,
                ],
            )
            .map(Arc::new);
            match &structures {
                Some(s) => context.info.add_type_loader(s.loader()),
                None => tracing::warn!("OPC UA ISA-95's namespace is missing: no job orders"),
            }
            Nodes {
                machinery,
                structures,
                cleared_jobs: cleared2,
                job_commands: tokio::sync::Mutex::new(()),
                namespace: NamespaceMetadata {
                    namespace_uri: namespace_uri.clone(),
                    namespace_index: index,
                    ..Default::default()
                },
                scopes,
                users: users2,
                bus,
                operator,
                poked: poked2,
                last_refusals: refusal2,
            }
        },
    );
    let conditions = Arc::new(std::sync::Mutex::new(Conditions::default()));
    let falc_nodes = Arc::new(std::sync::OnceLock::new());
    let (conditions2, falc_nodes2) = (conditions.clone(), falc_nodes.clone());
    let path = "/";
    // The conditions' methods first: they are answered before the core
    // manager, which owns their nodes (`condition_methods`).
    let mut builder = ServerBuilder::new()
        .without_node_managers()
        .with_node_manager(move |context: ServerContext| {
            ConditionMethods::new(&context, conditions2, falc_nodes2)
        })
        .with_node_manager(InMemoryNodeManagerBuilder::new(CoreNodeManagerBuilder))
        .with_node_manager(DiagnosticsNodeManagerBuilder)
        // The companion specifications' types, as published
        // (`falc_opcua_models`).
        .with_node_manager(simple_node_manager_imports(
            vec![
                Box::new(falc_opcua_models::di::DiNamespace),
                Box::new(falc_opcua_models::machinery::MachineryNamespace),
                Box::new(falc_opcua_models::isa95::Isa95JobControlNamespace),
                Box::new(falc_opcua_models::jobs::MachineryJobsNamespace),
                Box::new(falc_opcua_models::result::MachineryResultNamespace),
            ],
            "companion specifications",
        ))
        .application_name(format!("FALC {what} {name}"))
        .application_uri(format!("urn:falc:{name}:opcua"))
        .product_uri("urn:falc:opcua")
        .build_info(BuildInfo {
            product_uri: "urn:falc:opcua".into(),
            manufacturer_name: "FALC".into(),
            product_name: "falc-opcua".into(),
            software_version: env!("CARGO_PKG_VERSION").into(),
            build_number: "1".into(),
            build_date: DateTime::now(),
        })
        .host(endpoint.host.clone())
        .port(endpoint.port)
        .pki_dir(endpoint.pki_dir.clone())
        .create_sample_keypair(true)
        .certificate_path("own/cert.der")
        .private_key_path("private/private.pem")
        .trust_client_certs(false)
        .discovery_urls(vec![path.to_owned()])
        .with_authenticator(users as Arc<dyn opcua::server::authenticator::AuthManager>)
        .with_node_manager(manager)
        // Subscribers hear of a change within 20–25 ms of the gateway's
        // write (async-opcua's default is 100 ms).
        .subscription_poll_interval_ms(TICK_MS);
    builder
        .limits_mut()
        .subscriptions
        .min_publishing_interval_ms = PUBLISH_MS as f64;
    // Values change only when the cell does (the gateway writes on the
    // operator's word), so a monitored item that asks for sampling
    // interval 0 gets every change as it is written (`space::REFRESH`
    // says what happens with an interval).
    builder.limits_mut().subscriptions.min_sampling_interval_ms = 0.0;
    let none: [String; 0] = [];
    use opcua::crypto::SecurityPolicy as P;
    use opcua::types::MessageSecurityMode as M;
    let mut endpoints: Vec<(&str, P, M)> = vec![
        (
            "basic256sha256_sign_encrypt",
            P::Basic256Sha256,
            M::SignAndEncrypt,
        ),
        (
            "aes256_sha256_rsapss_sign_encrypt",
            P::Aes256Sha256RsaPss,
            M::SignAndEncrypt,
        ),
        (
            "aes128_sha256_rsaoaep_sign_encrypt",
            P::Aes128Sha256RsaOaep,
            M::SignAndEncrypt,
        ),
        (
            "aes128_sha256_rsaoaep_sign",
            P::Aes128Sha256RsaOaep,
            M::Sign,
        ),
    ];
    if endpoint.insecure {
        endpoints.push(("none", P::None, M::None));
    }
    let endpoints = endpoints
        .into_iter()
        .map(|(name, p, m)| (name, ServerEndpoint::new(path, p, m, &none)));
    for (name, e) in endpoints {
        builder = builder.add_endpoint(name, e);
    }
    // The server's key is made inside a private directory, and kept
    // private (async-opcua writes it with the default mode).
    credentials::private_dir(&endpoint.pki_dir).map_err(|e| e.to_string())?;
    let (server, handle) = builder.build()?;
    let key = endpoint.pki_dir.join("private/private.pem");
    std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o600))
        .map_err(|e| format!("cannot make {} private (chmod 600): {e}", key.display()))?;
    let nodes = handle
        .node_managers()
        .get_of_type::<NodeManager>()
        .ok_or("the FALC node manager is missing")?;
    let ns = handle
        .get_namespace_index(&uri)
        .ok_or("the FALC namespace is missing")?;
    let _ = falc_nodes.set(nodes.clone());
    Ok((
        server,
        Running {
            handle,
            nodes,
            ns,
            poked,
            last_refusals,
            conditions,
            cleared_jobs,
        },
    ))
}
/// How many rejected client certificates the gateway keeps for an
/// administrator to move to `trusted/`: a stranger's every attempt writes
/// one (no credentials needed), so the oldest beyond these are removed.
pub const KEEP_REJECTED: usize = 100;

/// Keeps the newest `keep` files of `dir` (a PKI's `rejected/`), removing
/// the rest; how many were removed. A missing directory has none.
pub fn prune_rejected(dir: &std::path::Path, keep: usize) -> std::io::Result<usize> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(e),
    };
    let mut files: Vec<(std::time::SystemTime, std::path::PathBuf)> = entries
        .filter_map(Result::ok)
        .filter_map(|e| {
            let m = e.metadata().ok()?;
            m.is_file()
                .then(|| (m.modified().unwrap_or(std::time::UNIX_EPOCH), e.path()))
        })
        .collect();
    if files.len() <= keep {
        return Ok(0);
    }
    files.sort();
    let old = files.len() - keep;
    let mut removed = 0;
    for (_, path) in files.into_iter().take(old) {
        if std::fs::remove_file(&path).is_ok() {
            removed += 1;
        }
    }
    Ok(removed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rejected_folder_keeps_the_newest_certificates_only() {
        let dir = tempfile::tempdir().expect("tempdir");
        let rejected = dir.path().join("rejected");
        assert_eq!(prune_rejected(&rejected, 3).ok(), Some(0), "none yet");
        std::fs::create_dir(&rejected).expect("mkdir");
        let t0 = std::time::SystemTime::now();
        for i in 0..10u64 {
            let f = rejected.join(format!("stranger-{i}.der"));
            std::fs::write(&f, b"cert").expect("write");
            let when = t0 - std::time::Duration::from_secs(100 - i);
            std::fs::File::options()
                .write(true)
                .open(&f)
                .and_then(|h| h.set_modified(when))
                .expect("mtime");
        }
        assert_eq!(prune_rejected(&rejected, 3).ok(), Some(7));
        let mut left: Vec<String> = std::fs::read_dir(&rejected)
            .expect("dir")
            .filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
            .collect();
        left.sort();
        assert_eq!(left, ["stranger-7.der", "stranger-8.der", "stranger-9.der"]);
    }
}
