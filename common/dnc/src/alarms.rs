//! RCM message numbers → `RobotStatusDetail` and what the workstation does
//! with them, as data (docs/the-1992-cell.md §5); and the detail of the robot's
//! own program status ([`status_detail`]).
//!
//! The thesis' table maps a message number to two bytes: the high byte is
//! the robotVMDState (0–5), extended with 6 = "send a confirmation to the
//! robot" and 7 = "do nothing"; the low byte holds the specific-status
//! bits (bit 0 safetyInterlocksViolated, bit 2 allCalibrated, bit 3
//! localControl). Its printed part (0–25) is kept exactly; the scan cut the
//! rest, so 26–999 are defined here, with the events the twin can raise.
//!
//! The alarm class follows from the row ([`AlarmEntry::class`]): safety
//! where the safety interlocks are violated (24, 40), process for an
//! aborted weld, a warning for 3, 30, 31 and 60–99, device for the rest.
//!
//! | codes | detail | effect | meaning |
//! |---|---|---|---|
//! | 0, 2, 4–7, 9–23, 25 | 0x0504 | alarm | manual intervention required (printed) |
//! | 1, 8 | 0x050c | alarm | manual intervention required, robot under local control (printed) |
//! | 3 | 0x0604 | confirm | the RCM asks for a confirmation (printed); the workstation confirms with `K003` |
//! | 24 | 0x0505 | alarm | emergency stop: safety interlocks violated (printed) |
//! | 30 | 0x0404 | paused | a person in the robot's work area: motion paused |
//! | 31 | 0x0304 | resumed | the work area is clear: motion resumes |
//! | 40 | 0x0505 | failed_danger | hardware limit switch hit: outside its own work area |
//! | 41 | 0x0504 | failed_safe | software limit reached: stopped safely |
//! | 50 | 0x0704 | bad_product | weld aborted (arc lost): the program ends, the product is bad |
//! | 60–99 | 0x0704 | info | informational messages: logged, nothing else |
//! | all other codes (26–29, 32–39, 42–49, 51–59, 100–999) | 0x0504 | alarm | unknown to FALC: treated as an alarm needing a person |

use crate::telegram::{Mode, ProgramState};
use falc_model::alarm::AlarmClass;
use falc_model::mms::vmd::{RobotStatusDetail, RobotVmdState};

/// What the workstation does with an RCM message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Effect {
    /// Stop, report the alarm (the cell stops).
    Alarm,
    /// Send a confirmation telegram (`K`) to the robot.
    Confirm,
    /// The running job is paused (time limits freeze).
    Paused,
    /// … and goes on.
    Resumed,
    /// `failed_danger`.
    FailedDanger,
    /// `failed_safe`.
    FailedSafe,
    /// `bad_product` at the program's end.
    BadProduct,
    /// Log only.
    Info,
}

/// One row of the table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AlarmEntry {
    /// High byte: robotVMDState, or 6 (confirm), 7 (nothing).
    pub high: u8,
    /// Low byte: specific-status bits.
    pub low: u8,
    /// What to do.
    pub effect: Effect,
    /// For people.
    pub meaning: &'static str,
}

/// The fixed mask: power-on cannot be seen over DNC, units are irrelevant.
pub const MASK: u8 = RobotStatusDetail::SAFETY_INTERLOCKS_VIOLATED
    | RobotStatusDetail::ALL_CALIBRATED
    | RobotStatusDetail::LOCAL_CONTROL;

/// The table entry of an RCM message number.
pub fn lookup(code: u16) -> AlarmEntry {
    let e = |high, low, effect, meaning| AlarmEntry {
        high,
        low,
        effect,
        meaning,
    };
    match code {
        1 | 8 => e(
            5,
            0x0c,
            Effect::Alarm,
            "manual intervention required; robot under local control",
        ),
        3 => e(
            6,
            0x04,
            Effect::Confirm,
            "the robot controller asks for a confirmation",
        ),
        24 => e(
            5,
            0x05,
            Effect::Alarm,
            "emergency stop: safety interlocks violated",
        ),
        0 | 2 | 4..=7 | 9..=23 | 25 => e(5, 0x04, Effect::Alarm, "manual intervention required"),
        30 => e(
            4,
            0x04,
            Effect::Paused,
            "a person in the robot's work area: motion paused",
        ),
        31 => e(
            3,
            0x04,
            Effect::Resumed,
            "the work area is clear: motion resumes",
        ),
        40 => e(5, 0x05, Effect::FailedDanger, "hardware limit switch hit"),
        41 => e(
            5,
            0x04,
            Effect::FailedSafe,
            "software limit reached: stopped safely",
        ),
        50 => e(
            7,
            0x04,
            Effect::BadProduct,
            "weld aborted (arc lost): product bad",
        ),
        60..=99 => e(7, 0x04, Effect::Info, "information"),
        _ => e(
            5,
            0x04,
            Effect::Alarm,
            "unknown robot message: manual intervention required",
        ),
    }
}

impl AlarmEntry {
    /// The alarm class: safety when the safety interlocks are violated
    /// (emergency stop, hardware limit switch), a warning for a person in
    /// the work area or a message, process for an aborted weld, device for
    /// everything else the robot reports.
    pub fn class(self) -> AlarmClass {
        if self.low & RobotStatusDetail::SAFETY_INTERLOCKS_VIOLATED != 0 {
            AlarmClass::Safety
        } else {
            match self.effect {
                Effect::Paused | Effect::Resumed | Effect::Info | Effect::Confirm => {
                    AlarmClass::Warning
                }
                Effect::BadProduct => AlarmClass::Process,
                Effect::Alarm | Effect::FailedSafe | Effect::FailedDanger => AlarmClass::Device,
            }
        }
    }

    /// The two bytes of the thesis' table.
    pub fn word(self) -> u16 {
        u16::from(self.high) << 8 | u16::from(self.low)
    }

    /// The RobotStatusDetail to report, if the high byte is a robot state
    /// (6 and 7 leave the state as it was: None).
    pub fn detail(self) -> Option<RobotStatusDetail> {
        let state = match self.high {
            0 => RobotVmdState::Idle,
            1 => RobotVmdState::Loaded,
            2 => RobotVmdState::Ready,
            3 => RobotVmdState::Executing,
            4 => RobotVmdState::MotionPaused,
            5 => RobotVmdState::ManualInterventionRequired,
            _ => return None,
        };
        Some(RobotStatusDetail {
            state,
            specific: self.low & MASK,
            mask: MASK,
        })
    }
}

/// The robot's status detail from its own program status telegram (`P`):
/// idle, loaded, executing, motion-paused, ready; all calibrated; local
/// control unless in automatic-external mode. The alarm table gives the
/// detail of an alarm message, this one the detail the robot reports once
/// it works again.
pub fn status_detail(state: ProgramState, mode: Mode) -> RobotStatusDetail {
    let state = match state {
        ProgramState::Idle => RobotVmdState::Idle,
        ProgramState::Selected => RobotVmdState::Loaded,
        ProgramState::Running => RobotVmdState::Executing,
        ProgramState::Paused => RobotVmdState::MotionPaused,
        ProgramState::Stopped => RobotVmdState::Ready,
    };
    let local = if mode == Mode::AutomaticExternal {
        0
    } else {
        RobotStatusDetail::LOCAL_CONTROL
    };
    RobotStatusDetail {
        state,
        specific: RobotStatusDetail::ALL_CALIBRATED | local,
        mask: MASK,
    }
}

#[cfg(test)]
#[allow(clippy::indexing_slicing)]
mod tests {
    use super::*;

    #[test]
    fn classes_follow_from_the_table() {
        assert_eq!(lookup(24).class(), AlarmClass::Safety);
        assert_eq!(lookup(40).class(), AlarmClass::Safety);
        assert_eq!(lookup(1).class(), AlarmClass::Device);
        assert_eq!(lookup(30).class(), AlarmClass::Warning);
        assert_eq!(lookup(50).class(), AlarmClass::Process);
        assert_eq!(lookup(999).class(), AlarmClass::Device);
    }

    #[test]
    fn the_printed_part_of_the_thesis_table() {
        let printed: [(u16, u16); 11] = [
            (0, 0x0504),
            (1, 0x050c),
            (2, 0x0504),
            (3, 0x0604),
            (4, 0x0504),
            (7, 0x0504),
            (8, 0x050c),
            (9, 0x0504),
            (23, 0x0504),
            (24, 0x0505),
            (25, 0x0504),
        ];
        for (code, word) in printed {
            assert_eq!(lookup(code).word(), word, "code {code}");
        }
    }

    #[test]
    fn every_code_has_an_entry_and_robot_states_carry_detail() {
        for code in 0..=999u16 {
            let e = lookup(code);
            assert!(e.high <= 7, "code {code}");
            assert_eq!(e.detail().is_some(), e.high <= 5, "code {code}");
        }
        let estop = lookup(24).detail().expect("a robot state");
        assert_eq!(estop.state, RobotVmdState::ManualInterventionRequired);
        assert_eq!(
            estop.specific & RobotStatusDetail::SAFETY_INTERLOCKS_VIOLATED,
            1
        );
        assert_eq!(lookup(30).effect, Effect::Paused);
        assert_eq!(lookup(40).effect, Effect::FailedDanger);
        assert_eq!(lookup(50).effect, Effect::BadProduct);
        assert_eq!(lookup(777).effect, Effect::Alarm);
    }
}
