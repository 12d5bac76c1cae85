//! Each cell as a machine of OPC 40001-1 Machinery, so that an MES finds
//! it the standard way: in the Machines folder, with its Identification
//! (DI's nameplate properties, Machinery's MachineIdentificationType) and
//! its MachineryItemState and MachineryOperationMode state machines under
//! MachineryBuildingBlocks. The types are the published models'
//! (`falc_opcua_models`, generated from their NodeSet2 files); this module
//! lays out the instances and maps FALC's state onto theirs (sans-I/O:
//! [`states`]).

use crate::space::{Look, Value};
use falc_model::mode::CellMode;
use falc_model::topology::Identification;
use falc_opcua_models::machinery::ids::{
    ObjectId as MachineryObject, ObjectTypeId as MachineryType,
};
use opcua::nodes::ReferenceDirection;
use opcua::server::address_space::{AddressSpace, ObjectBuilder, VariableBuilder};
use opcua::types::{
    DataTypeId, LocalizedText, NodeId, ObjectTypeId, QualifiedName, ReferenceTypeId, UAString,
    VariableTypeId, Variant,
};

/// The folder of the gateway's machines in its own namespace (under the
/// Machinery namespace's Machines folder).
pub const MACHINES: &str = "Machines";

/// One cell as a machine.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Machine {
    /// Its browse name and the last part of its node ids (the cell id).
    pub name: String,
    /// How it names itself.
    pub identification: Identification,
}

impl Machine {
    /// The node id of `name` under it.
    pub fn id(&self, name: &str) -> String {
        format!("{MACHINES}.{}.{name}", self.name)
    }

    /// Its object's node id.
    pub fn object(&self) -> String {
        format!("{MACHINES}.{}", self.name)
    }
}

/// The namespace indexes the machines' nodes use.
#[derive(Debug, Clone, Copy)]
pub struct Namespaces {
    /// The gateway's own.
    pub own: u16,
    /// OPC 10000-100 DI.
    pub di: u16,
    /// OPC 40001-1 Machinery.
    pub machinery: u16,
    /// OPC 10031-4 ISA-95 Job Control.
    pub isa95: u16,
    /// OPC 40001-3 Machinery Job Management.
    pub jobs: u16,
    /// OPC 40001-101 Machinery Result Transfer.
    pub result: u16,
}

/// A state of a Machinery state machine: its name and its state object in
/// the Machinery namespace.
fn state(name: &str, id: MachineryObject) -> (String, u32) {
    (name.to_string(), id as u32)
}

/// The cell's MachineryItemState and MachineryOperationMode now.
/// - item state: NotAvailable while the operator does not answer,
///   OutOfService in maintenance mode, Executing while an order runs
///   (PackML Execute or Held), NotExecuting otherwise;
/// - operation mode: Processing in auto, Setup in step mode (an operator
///   steps the recipes by hand), Maintenance in maintenance mode, None
///   while the operator does not answer.
pub fn states(look: &Look, packml: crate::packml::State) -> ((String, u32), (String, u32)) {
    use MachineryObject as O;
    let Some(status) = look.status.as_ref() else {
        return (
            state(
                "NotAvailable",
                O::MachineryItemState_StateMachineType_NotAvailable,
            ),
            state("None", O::MachineryOperationModeStateMachineType_None),
        );
    };
    let item = match (status.mode, packml) {
        (CellMode::Maintenance, _) => state(
            "OutOfService",
            O::MachineryItemState_StateMachineType_OutOfService,
        ),
        (_, crate::packml::State::Execute | crate::packml::State::Held) => state(
            "Executing",
            O::MachineryItemState_StateMachineType_Executing,
        ),
        _ => state(
            "NotExecuting",
            O::MachineryItemState_StateMachineType_NotExecuting,
        ),
    };
    let mode = match status.mode {
        CellMode::Auto => state(
            "Processing",
            O::MachineryOperationModeStateMachineType_Processing,
        ),
        CellMode::Step => state("Setup", O::MachineryOperationModeStateMachineType_Setup),
        CellMode::Maintenance => state(
            "Maintenance",
            O::MachineryOperationModeStateMachineType_Maintenance,
        ),
    };
    (item, mode)
}

/// The machine's values for this look (the states' CurrentState and its
/// Id).
pub fn values(
    m: &Machine,
    look: &Look,
    packml: crate::packml::State,
    put: &mut dyn FnMut(String, Value),
) {
    let ((item, item_id), (mode, mode_id)) = states(look, packml);
    let base = "MachineryBuildingBlocks";
    put(
        m.id(&format!("{base}.MachineryItemState.CurrentState")),
        Value::Localized(item),
    );
    put(
        m.id(&format!("{base}.MachineryItemState.CurrentState.Id")),
        Value::StateId(item_id),
    );
    put(
        m.id(&format!("{base}.MachineryOperationMode.CurrentState")),
        Value::Localized(mode),
    );
    put(
        m.id(&format!("{base}.MachineryOperationMode.CurrentState.Id")),
        Value::StateId(mode_id),
    );
}

/// Lays out machine `m`: its object in the Machines folder, its
/// Identification, its building blocks and state machines (their
/// CurrentState written by the look loop, [`values`]).
pub fn build(space: &mut AddressSpace, ns: Namespaces, m: &Machine) {
    let own = |id: &str| NodeId::new(ns.own, UAString::from(id));
    let machinery_type = |t: MachineryType| NodeId::new(ns.machinery, t as u32);
    let machines = NodeId::new(ns.machinery, MachineryObject::Machines as u32);
    let object = own(&m.object());
    ObjectBuilder::new(
        &object,
        QualifiedName::new(ns.own, m.name.as_str()),
        m.name.as_str(),
    )
    .has_type_definition(ObjectTypeId::BaseObjectType)
    .organized_by(machines)
    .insert(space);

    // Identification (DI's nameplate properties in the DI namespace).
    let ident = own(&m.id("Identification"));
    ObjectBuilder::new(
        &ident,
        QualifiedName::new(ns.di, "Identification"),
        "Identification",
    )
    .has_type_definition(machinery_type(MachineryType::MachineIdentificationType))
    .reference(
        &object,
        ReferenceTypeId::HasAddIn,
        ReferenceDirection::Inverse,
    )
    .insert(space);
    let i = &m.identification;
    let serial = i.serial_number.clone().unwrap_or_else(|| m.name.clone());
    let properties: [(&str, Variant, DataTypeId); 5] = [
        (
            "Manufacturer",
            LocalizedText::from(i.manufacturer.as_str()).into(),
            DataTypeId::LocalizedText,
        ),
        (
            "Model",
            LocalizedText::from(i.model.as_str()).into(),
            DataTypeId::LocalizedText,
        ),
        ("SerialNumber", serial.as_str().into(), DataTypeId::String),
        (
            "ProductInstanceUri",
            format!(
                "urn:falc:machine:{}:{serial}",
                i.manufacturer.replace(' ', "-")
            )
            .into(),
            DataTypeId::String,
        ),
        (
            "SoftwareRevision",
            env!("CARGO_PKG_VERSION").into(),
            DataTypeId::String,
        ),
    ];
    for (name, value, data_type) in properties {
        VariableBuilder::new(
            &own(&m.id(&format!("Identification.{name}"))),
            QualifiedName::new(ns.di, name),
            name,
        )
        .data_type(data_type)
        .value(value)
        .has_type_definition(VariableTypeId::PropertyType)
        .property_of(ident.clone())
        .insert(space);
    }

    // The building blocks: the Identification again, and the states.
    let blocks = own(&m.id("MachineryBuildingBlocks"));
    ObjectBuilder::new(
        &blocks,
        QualifiedName::new(ns.machinery, "MachineryBuildingBlocks"),
        "MachineryBuildingBlocks",
    )
    .has_type_definition(ObjectTypeId::FolderType)
    .component_of(object.clone())
    .reference(
        &ident,
        ReferenceTypeId::HasAddIn,
        ReferenceDirection::Forward,
    )
    .insert(space);
    for (name, t) in [
        (
            "MachineryItemState",
            MachineryType::MachineryItemState_StateMachineType,
        ),
        (
            "MachineryOperationMode",
            MachineryType::MachineryOperationModeStateMachineType,
        ),
    ] {
        let machine_state = own(&m.id(&format!("MachineryBuildingBlocks.{name}")));
        ObjectBuilder::new(&machine_state, QualifiedName::new(ns.machinery, name), name)
            .has_type_definition(machinery_type(t))
            .reference(
                &blocks,
                ReferenceTypeId::HasAddIn,
                ReferenceDirection::Inverse,
            )
            .insert(space);
        let current = own(&m.id(&format!("MachineryBuildingBlocks.{name}.CurrentState")));
        VariableBuilder::new(
            &current,
            QualifiedName::new(0, "CurrentState"),
            "CurrentState",
        )
        .data_type(DataTypeId::LocalizedText)
        .value(LocalizedText::from(""))
        .has_type_definition(VariableTypeId::FiniteStateVariableType)
        .component_of(machine_state.clone())
        .insert(space);
        VariableBuilder::new(
            &own(&m.id(&format!("MachineryBuildingBlocks.{name}.CurrentState.Id"))),
            QualifiedName::new(0, "Id"),
            "Id",
        )
        .data_type(DataTypeId::NodeId)
        .value(NodeId::null())
        .has_type_definition(VariableTypeId::PropertyType)
        .property_of(current)
        .insert(space);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::packml::State;
    use falc_model::api::CellStatus;

    fn look(mode: CellMode) -> Look {
        Look {
            reachable: true,
            status: Some(CellStatus {
                mode,
                ..CellStatus::default()
            }),
            ..Look::default()
        }
    }

    #[test]
    fn the_cell_s_state_and_mode_are_machinery_s() {
        let name = |s: ((String, u32), (String, u32))| (s.0 .0, s.1 .0);
        assert_eq!(
            name(states(&Look::default(), State::Stopped)),
            ("NotAvailable".into(), "None".into())
        );
        assert_eq!(
            name(states(&look(CellMode::Auto), State::Execute)),
            ("Executing".into(), "Processing".into())
        );
        assert_eq!(
            name(states(&look(CellMode::Auto), State::Held)),
            ("Executing".into(), "Processing".into())
        );
        assert_eq!(
            name(states(&look(CellMode::Auto), State::Idle)),
            ("NotExecuting".into(), "Processing".into())
        );
        assert_eq!(
            name(states(&look(CellMode::Step), State::Idle)),
            ("NotExecuting".into(), "Setup".into())
        );
        assert_eq!(
            name(states(&look(CellMode::Maintenance), State::Execute)),
            ("OutOfService".into(), "Maintenance".into())
        );
        // The Id is the state's object in the Machinery namespace.
        let ((_, executing), (_, processing)) = states(&look(CellMode::Auto), State::Execute);
        assert_eq!(executing, 5006);
        assert_eq!(processing, 5026);
    }
}
