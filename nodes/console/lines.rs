//! One line per record as both the command line and the TUI show it (the
//! TUI takes its lines from here, not from the CLI's output).

use crate::clock::time_of_day_ms;
use falc_model::alarm::Alarm;
use falc_model::ids::printable;

/// One alarm as `falc alarms` prints it: number, time, class, station,
/// order, text, and its state (`active, needs ack`, `acknowledged by …`).
pub(crate) fn alarm(a: &Alarm) -> String {
    let order = a.order.map(|o| format!(" (order {o})")).unwrap_or_default();
    let state = match &a.acked {
        Some((who, at)) => format!("{} by {who} {}", a.state(), time_of_day_ms(*at)),
        None if a.blocks_start() => format!("{}, needs ack", a.state()),
        None => a.state().to_string(),
    };
    format!(
        "#{:<3} {} {:<13} {:<10} {}{order}  [{}]",
        a.id,
        time_of_day_ms(a.raised_ms),
        a.class.as_str(),
        a.station,
        printable(&a.text),
        printable(&state)
    )
}
