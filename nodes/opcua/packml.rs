//! The cell's state and mode in PackML terms (ISA-TR88.00.02): what a
//! plant's SCADA expects to read of a machine. FALC has no state machine
//! of that shape; this module maps its order list, running order, waiting
//! question, step mode and alarms onto the PackML states, one rule each:
//!
//! | FALC | PackML state |
//! |---|---|
//! | an alarm stopped the list (`ack`, then `start`) | Aborted (9) |
//! | the list runs, an order runs, no one is waited for | Execute (6) |
//! | the list runs, a question waits for its answer, or a step waits in step mode | Held (11) |
//! | the list runs between two orders (the next being started) | Starting (3) |
//! | the list is idle, the last order was stopped by an operator | Stopped (2) |
//! | the list is idle, the cell is not associated | Stopped (2) |
//! | the list is idle otherwise (ready for `start`) | Idle (4) |
//!
//! and the mode: auto → Production (1), maintenance → Maintenance (2),
//! step → Manual (3).

use falc_model::api::{CellStatus, ListState};
use falc_model::mode::CellMode;
use falc_model::records::OrderState;

/// A PackML state: its number and name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// 2.
    Stopped,
    /// 3.
    Starting,
    /// 4.
    Idle,
    /// 6.
    Execute,
    /// 9.
    Aborted,
    /// 11.
    Held,
}

impl State {
    /// The state number of ISA-TR88.00.02.
    pub fn code(self) -> i32 {
        match self {
            Self::Stopped => 2,
            Self::Starting => 3,
            Self::Idle => 4,
            Self::Execute => 6,
            Self::Aborted => 9,
            Self::Held => 11,
        }
    }

    /// Its name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Stopped => "Stopped",
            Self::Starting => "Starting",
            Self::Idle => "Idle",
            Self::Execute => "Execute",
            Self::Aborted => "Aborted",
            Self::Held => "Held",
        }
    }
}

/// The cell's PackML state from its status and how the newest ended order
/// ended (None: no order ended yet).
pub fn state(status: &CellStatus, last_ended: Option<OrderState>) -> State {
    let held = status.question.is_some()
        || status
            .stations
            .iter()
            .any(|s| s.status.as_ref().is_some_and(|v| v.held.is_some()));
    match status.list {
        ListState::Alarm => State::Aborted,
        ListState::Running if status.running.is_none() => State::Starting,
        ListState::Running if held => State::Held,
        ListState::Running => State::Execute,
        ListState::Idle if !status.cell_associated => State::Stopped,
        ListState::Idle if last_ended == Some(OrderState::Stopped) => State::Stopped,
        ListState::Idle => State::Idle,
    }
}

/// The PackML unit mode: number and name.
pub fn unit_mode(mode: CellMode) -> (i32, &'static str) {
    match mode {
        CellMode::Auto => (1, "Production"),
        CellMode::Maintenance => (2, "Maintenance"),
        CellMode::Step => (3, "Manual"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use falc_model::api::StationView;
    use falc_model::ids::StationName;
    use falc_model::mms::vmd::VmdStatus;
    use falc_model::mode::HeldStep;
    use falc_model::records::Order;

    fn idle() -> CellStatus {
        CellStatus {
            cell_associated: true,
            ..CellStatus::default()
        }
    }

    fn running() -> CellStatus {
        CellStatus {
            list: ListState::Running,
            running: Some(Order {
                id: 1,
                recipe: "dikdroog".into(),
                state: OrderState::Running,
                added_by: "console".into(),
                started_ms: Some(0),
                ended_ms: None,
                result: None,
                cell: Some("falc1".into()),
                wanted: None,
                priority: 0,
                due_ms: None,
                job_order: None,
            }),
            ..idle()
        }
    }

    #[test]
    fn every_rule_of_the_table() {
        assert_eq!(state(&idle(), None), State::Idle);
        assert_eq!(state(&idle(), Some(OrderState::Done)), State::Idle);
        assert_eq!(state(&idle(), Some(OrderState::Failed)), State::Idle);
        assert_eq!(state(&idle(), Some(OrderState::Stopped)), State::Stopped);
        let lost = CellStatus {
            cell_associated: false,
            ..idle()
        };
        assert_eq!(state(&lost, None), State::Stopped);
        assert_eq!(state(&running(), None), State::Execute);
        let asking = CellStatus {
            question: Some("OK?".into()),
            ..running()
        };
        assert_eq!(state(&asking, None), State::Held);
        let stepping = CellStatus {
            stations: vec![StationView {
                name: StationName::new("cell").expect("valid"),
                status: Some(VmdStatus {
                    held: Some(HeldStep {
                        state: 1,
                        command: "output".into(),
                    }),
                    ..VmdStatus::default()
                }),
                connected: true,
            }],
            ..running()
        };
        assert_eq!(state(&stepping, None), State::Held);
        let between = CellStatus {
            running: None,
            ..running()
        };
        assert_eq!(state(&between, None), State::Starting);
        let alarm = CellStatus {
            list: ListState::Alarm,
            ..running()
        };
        assert_eq!(state(&alarm, Some(OrderState::Failed)), State::Aborted);
        for s in [
            State::Stopped,
            State::Starting,
            State::Idle,
            State::Execute,
            State::Aborted,
            State::Held,
        ] {
            assert!(!s.name().is_empty() && s.code() > 0);
        }
        assert_eq!(unit_mode(CellMode::Step), (3, "Manual"));
        assert_eq!(unit_mode(CellMode::Auto).1, "Production");
    }
}
