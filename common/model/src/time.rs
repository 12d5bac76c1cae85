//! Times as records and journal lines write them: milliseconds since the
//! Unix epoch in words.

/// `ms` since the Unix epoch as `YYYY-MM-DD HH:MM UTC`, for a record's
/// text (consoles show times in their own zone; a journal line says it
/// once for all).
pub fn utc_text(ms: i64) -> String {
    let minutes = ms.div_euclid(60_000);
    let (days, minute) = (minutes.div_euclid(1440), minutes.rem_euclid(1440));
    // Days to a civil date (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02} {:02}:{:02} UTC",
        minute / 60,
        minute % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_text_is_the_civil_date_and_time() {
        assert_eq!(utc_text(0), "1970-01-01 00:00 UTC");
        // 2026-11-23 12:34:56.789 UTC.
        assert_eq!(utc_text(1_795_437_296_789), "2026-11-23 12:34 UTC");
        assert_eq!(utc_text(951_782_400_000), "2000-02-29 00:00 UTC");
        assert_eq!(utc_text(-60_000), "1969-12-31 23:59 UTC");
    }
}
