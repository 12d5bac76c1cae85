//! Journal and alarm time stamps as the console shows them: the time of day
//! in the console PC's own time zone (jiff: `TZ`, else `/etc/localtime`;
//! UTC where neither says otherwise). The records keep ms since the Unix
//! epoch; only the console turns them into local time.

use jiff::tz::TimeZone;
use jiff::Timestamp;

/// `HH:MM:SS` in local time.
pub fn time_of_day(ms: i64) -> String {
    in_zone(ms, &TimeZone::system(), "%H:%M:%S")
}

/// `HH:MM:SS.mmm` in local time.
pub fn time_of_day_ms(ms: i64) -> String {
    in_zone(ms, &TimeZone::system(), "%H:%M:%S%.3f")
}

fn in_zone(ms: i64, tz: &TimeZone, format: &str) -> String {
    match Timestamp::from_millisecond(ms) {
        Ok(t) => t.to_zoned(tz.clone()).strftime(format).to_string(),
        // Not a time jiff can show (a corrupt record): said as it is.
        Err(_) => format!("@{ms}ms"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use jiff::tz::offset;

    #[test]
    fn shown_in_the_zone_given() {
        // 2026-11-23 12:34:56.789 UTC.
        let ms = 1_795_437_296_789;
        assert_eq!(in_zone(ms, &TimeZone::UTC, "%H:%M:%S%.3f"), "12:34:56.789");
        let cet = TimeZone::fixed(offset(1));
        assert_eq!(in_zone(ms, &cet, "%H:%M:%S"), "13:34:56");
        assert_eq!(
            in_zone(i64::MAX, &cet, "%H:%M:%S"),
            format!("@{}ms", i64::MAX)
        );
    }
}
