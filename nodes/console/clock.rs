//! Journal and alarm time stamps as the console shows them: the time of day
//! in the console PC's own time zone (jiff: `TZ`, else `/etc/localtime`;
//! UTC where neither says otherwise). The records keep ms since the Unix
//! epoch; only the console turns them into local time.

use jiff::tz::TimeZone;
use jiff::Timestamp;

/// Milliseconds since the Unix epoch, now.
pub fn now_ms() -> i64 {
    Timestamp::now().as_millisecond()
}

/// `HH:MM:SS` in local time.
pub fn time_of_day(ms: i64) -> String {
    in_zone(ms, &TimeZone::system(), "%H:%M:%S")
}

/// `HH:MM:SS.mmm` in local time.
pub fn time_of_day_ms(ms: i64) -> String {
    in_zone(ms, &TimeZone::system(), "%H:%M:%S%.3f")
}

/// `YYYY-MM-DD HH:MM` in local time.
pub fn date_time(ms: i64) -> String {
    in_zone(ms, &TimeZone::system(), "%Y-%m-%d %H:%M")
}

/// A due time as `falc order add --due` takes it, in ms since the Unix
/// epoch: with an offset (`2026-11-25T14:00+01:00`), or in the console
/// PC's time zone (`2026-11-25T14:00`, `2026-11-25 14:00`, `14:00` for
/// today).
pub fn parse_due(text: &str) -> Result<i64, String> {
    due_in(text, &TimeZone::system(), jiff::Zoned::now().date())
}

fn due_in(text: &str, tz: &TimeZone, today: jiff::civil::Date) -> Result<i64, String> {
    let text = text.trim();
    let bad = || {
        format!(
            "due time \"{}\": give 2026-11-25T14:00, 2026-11-25 14:00, 14:00 or \
             2026-11-25T14:00+01:00",
            falc_model::ids::excerpt(text)
        )
    };
    let at = if let Ok(t) = text.parse::<Timestamp>() {
        t
    } else if let Ok(dt) = text.parse::<jiff::civil::DateTime>() {
        dt.to_zoned(tz.clone()).map_err(|_| bad())?.timestamp()
    } else if let Ok(time) = text.parse::<jiff::civil::Time>() {
        today
            .to_datetime(time)
            .to_zoned(tz.clone())
            .map_err(|_| bad())?
            .timestamp()
    } else {
        return Err(bad());
    };
    Ok(at.as_millisecond())
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
    fn a_due_time_is_read_in_the_zone_given_or_with_its_offset() {
        let cet = TimeZone::fixed(offset(1));
        let today = jiff::civil::date(2026, 11, 25);
        // 2026-11-25 13:00 UTC.
        let ms = 1_795_611_600_000;
        assert_eq!(due_in("2026-11-25T14:00", &cet, today), Ok(ms));
        assert_eq!(due_in("2026-11-25 14:00", &cet, today), Ok(ms));
        assert_eq!(due_in("14:00", &cet, today), Ok(ms));
        assert_eq!(due_in("2026-11-25T13:00Z", &cet, today), Ok(ms));
        assert_eq!(due_in("2026-11-25T15:00+02:00", &cet, today), Ok(ms));
        let e = due_in("tomorrow\x1b[2J", &cet, today).expect_err("refused");
        assert!(
            e.contains("tomorrow\\u{1b}[2J") && e.contains("14:00"),
            "{e}"
        );
    }

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
