//! Actuator feedback supervision, sans-I/O: for every actuator the
//! equipment file pairs with a feedback (`[[feedback]]`: a line's button
//! and its running lamp, a station's button and its busy lamp), the input
//! must follow the output within the file's time. Two mismatches are
//! faults, each the alarm class the file says (`fault`), naming the
//! actuator and the signal:
//!
//! - **not following**: FALC pressed the output and the input has not come
//!   on within the time (a stuck lamp, a line that does not start);
//! - **unasked**: the input came on while FALC did not hold the output
//!   (nor pressed it within the time before: a button pulsed to start a
//!   line), and stays on past the time (a line started by something else).
//!
//! A conveyor's feedback is edge-shaped, as its PLC works: a line runs on
//! after its button is released until the carrier reaches its end, and a
//! station stays busy while it holds a carrier; so a lamp that stays on
//! after its button was released, or goes off while it is held, is no
//! fault. The supervision runs also between jobs; it rests while the PLC
//! cannot act (no link, emergency stop, not ready), which has its own
//! alarm. Each mismatch is raised once, until it clears.

use crate::map::{Coil, Inputs};
use falc_equipment::file::FeedbackSpec;
use falc_model::alarm::Cause;
use std::time::Duration;

#[derive(Debug, Clone, Copy, Default)]
struct Watch {
    /// The output was pressed then, and its input not seen on since.
    pressed: Option<Duration>,
    /// The output's last press.
    last_press: Option<Duration>,
    /// The input came on then while the output was not held.
    unasked: Option<Duration>,
    /// The input's value in the last reading.
    was_on: bool,
    /// A mismatch was raised and has not cleared.
    raised: bool,
}

/// The supervision of every actuator with a feedback.
#[derive(Debug, Clone)]
pub struct Supervision {
    specs: Vec<FeedbackSpec>,
    watches: Vec<Watch>,
}

impl Supervision {
    /// Supervises `specs` (the equipment file's feedback).
    pub fn new(specs: &[FeedbackSpec]) -> Self {
        Self {
            specs: specs.to_vec(),
            watches: vec![Watch::default(); specs.len()],
        }
    }

    /// FALC wrote `value` to `coil` at `now`.
    pub fn wrote(&mut self, coil: Coil, value: bool, now: Duration) {
        for (s, w) in self.specs.iter().zip(self.watches.iter_mut()) {
            if s.output != coil {
                continue;
            }
            if value {
                w.pressed = Some(now);
                w.last_press = Some(now);
                w.unasked = None;
            } else {
                w.pressed = None;
            }
            w.raised = false;
        }
    }

    /// A reading at `now`; `held` says which outputs FALC holds.
    pub fn reading(&mut self, inputs: &Inputs, now: Duration, held: impl Fn(Coil) -> bool) {
        for (s, w) in self.specs.iter().zip(self.watches.iter_mut()) {
            let on = inputs.get(s.input);
            if on {
                w.pressed = None;
                let asked = held(s.output) || w.last_press.is_some_and(|t| now <= t + s.within);
                if !w.was_on && !asked {
                    w.unasked = Some(now);
                }
            } else {
                w.unasked = None;
            }
            if w.pressed.is_none() && w.unasked.is_none() {
                w.raised = false;
            }
            w.was_on = on;
        }
    }

    /// The PLC cannot act (no link, emergency stop, not ready): nothing is
    /// supervised until it can; the next reading starts afresh.
    pub fn rest(&mut self) {
        for w in &mut self.watches {
            *w = Watch::default();
        }
    }

    /// When a mismatch next comes due, if one can.
    pub fn poll_timeout(&self) -> Option<Duration> {
        self.specs
            .iter()
            .zip(&self.watches)
            .filter(|(_, w)| !w.raised)
            .filter_map(|(s, w)| {
                let a = w.pressed.map(|t| t + s.within);
                let b = w.unasked.map(|t| t + s.within);
                match (a, b) {
                    (Some(a), Some(b)) => Some(a.min(b)),
                    (a, b) => a.or(b),
                }
            })
            .min()
    }

    /// The first mismatch due at `now` (raised once), as the alarm the
    /// file says; `held` says which outputs FALC holds, `plc` names it.
    pub fn check(
        &mut self,
        now: Duration,
        held: impl Fn(Coil) -> bool,
        plc: &str,
    ) -> Option<Cause> {
        for (s, w) in self.specs.iter().zip(self.watches.iter_mut()) {
            if w.raised {
                continue;
            }
            let ms = s.within.as_millis();
            let text = match (w.pressed, w.unasked) {
                (Some(t), _) if held(s.output) && now >= t + s.within => format!(
                    "feedback: `{}` not on {ms} ms after `{}` was pressed (conveyor PLC at {plc})",
                    s.input, s.output
                ),
                (_, Some(t)) if !held(s.output) && now >= t + s.within => format!(
                    "feedback: `{}` on for {ms} ms without `{}` (conveyor PLC at {plc})",
                    s.input, s.output
                ),
                _ => continue,
            };
            w.raised = true;
            return Some(Cause::new(s.fault.alarm_class(), text));
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::Input;
    use falc_equipment::file::FaultClass;
    use falc_equipment::Equipment;
    use falc_model::alarm::AlarmClass;
    use falc_recipe::check::{Button, Signal};
    use std::sync::Arc;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    const K: Coil = Coil::Button(Button::Line('K'));

    fn spec() -> FeedbackSpec {
        FeedbackSpec {
            output: K,
            input: Input::Signal(Signal::Line('K')),
            within: ms(500),
            fault: FaultClass::Alarm,
        }
    }

    fn lamp(e: &Arc<Equipment>, on: bool) -> Inputs {
        let mut i = Inputs::new(e);
        i.set(Input::Signal(Signal::Line('K')), on);
        i
    }

    #[test]
    fn a_lamp_that_does_not_follow_its_button_is_an_alarm_once() {
        let e = Equipment::conveyor_1992();
        let mut s = Supervision::new(&[spec()]);
        s.wrote(K, true, ms(0));
        s.reading(&lamp(&e, false), ms(10), |_| true);
        assert_eq!(s.poll_timeout(), Some(ms(500)));
        assert_eq!(s.check(ms(499), |_| true, "plc"), None);
        let alarm = s.check(ms(500), |_| true, "plc").expect("due");
        assert_eq!(alarm.class, AlarmClass::Device);
        assert_eq!(
            alarm.text,
            "feedback: `line K running` not on 500 ms after `button line K` was pressed (conveyor PLC at plc)"
        );
        assert_eq!(s.check(ms(900), |_| true, "plc"), None, "raised once");
        assert_eq!(s.poll_timeout(), None);
        // Released and pressed again: supervised afresh.
        s.wrote(K, false, ms(1000));
        s.wrote(K, true, ms(1000));
        s.reading(&lamp(&e, true), ms(1010), |_| true);
        assert_eq!(s.check(ms(2000), |_| true, "plc"), None, "it followed");
    }

    #[test]
    fn a_lamp_lit_without_its_button_is_an_alarm_a_lamp_left_on_after_release_is_not() {
        let e = Equipment::conveyor_1992();
        let mut s = Supervision::new(&[spec()]);
        // Pressed, lit, released: the line runs on to its end. No fault.
        s.wrote(K, true, ms(0));
        s.reading(&lamp(&e, true), ms(10), |_| true);
        s.wrote(K, false, ms(20));
        s.reading(&lamp(&e, true), ms(30), |_| false);
        assert_eq!(s.check(ms(5000), |_| false, "plc"), None);
        s.reading(&lamp(&e, false), ms(6000), |_| false);
        // A pulse: pressed and released before the reading shows it lit.
        s.wrote(K, true, ms(6100));
        s.wrote(K, false, ms(6100));
        s.reading(&lamp(&e, true), ms(6110), |_| false);
        assert_eq!(s.check(ms(6900), |_| false, "plc"), None);
        s.reading(&lamp(&e, false), ms(6950), |_| false);
        // Lit with no button.
        s.reading(&lamp(&e, true), ms(7000), |_| false);
        assert_eq!(s.poll_timeout(), Some(ms(7500)));
        let alarm = s.check(ms(7500), |_| false, "plc").expect("due");
        assert_eq!(
            alarm.text,
            "feedback: `line K running` on for 500 ms without `button line K` (conveyor PLC at plc)"
        );
        // A short flicker is none.
        let mut s = Supervision::new(&[spec()]);
        s.reading(&lamp(&e, true), ms(0), |_| false);
        s.reading(&lamp(&e, false), ms(100), |_| false);
        assert_eq!(s.check(ms(1000), |_| false, "plc"), None);
        // Resting (an emergency stop) forgets what was pending.
        s.wrote(K, true, ms(2000));
        s.rest();
        assert_eq!(s.check(ms(9000), |_| true, "plc"), None);
    }

    #[test]
    fn a_warning_feedback_is_a_warning() {
        let mut s = Supervision::new(&[FeedbackSpec {
            fault: FaultClass::Warning,
            ..spec()
        }]);
        s.wrote(K, true, ms(0));
        let alarm = s.check(ms(600), |_| true, "plc").expect("due");
        assert_eq!(alarm.class, AlarmClass::Warning);
    }
}
