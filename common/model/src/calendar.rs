//! The shift calendar, as the topology writes it (`utc_offset`,
//! `[[shift]]`) and as it is checked: when a cell is planned to work, the
//! planned busy time of ISO 22400-2 that the figures are computed against
//! ([`crate::figures`]).

use serde::{Deserialize, Serialize};

const DAY_MS: i64 = 86_400_000;
const MINUTE_MS: i64 = 60_000;

/// The days of the week, Monday first (as `days` in a `[[shift]]`).
pub const WEEKDAYS: [&str; 7] = ["mon", "tue", "wed", "thu", "fri", "sat", "sun"];

/// One shift of the calendar, as written in the topology:
///
/// ```toml
/// utc_offset = "+01:00"
/// [[shift]]
/// name = "early"
/// start = "06:00"
/// end = "14:00"
/// days = ["mon", "tue", "wed", "thu", "fri"]
/// ```
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawShift {
    /// Its name (`early`).
    pub name: String,
    /// When it begins, `HH:MM` local time.
    pub start: String,
    /// When it ends, `HH:MM` (before `start`: the next day).
    pub end: String,
    /// The days it begins on (default: every day).
    #[serde(default)]
    pub days: Vec<String>,
}

/// One validated shift.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shift {
    /// Its name.
    pub name: String,
    /// Its start, minutes after local midnight.
    pub start_min: u16,
    /// Its length in minutes (1 to 1440).
    pub length_min: u16,
    /// The weekdays it begins on, Monday = 0.
    pub days: Vec<u8>,
}

/// When the cell is planned to work (ISO 22400's planned busy time):
/// the shifts, in local time at a fixed offset from UTC; no shift means
/// always.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Calendar {
    /// Local time minus UTC, in minutes.
    pub utc_offset_min: i16,
    /// The shifts (none: planned busy all the time).
    pub shifts: Vec<Shift>,
}

fn minutes_of(text: &str, what: &str) -> Result<u16, String> {
    let bad = || format!("{what} = \"{text}\" is not a time of day HH:MM");
    let (h, m) = text.split_once(':').ok_or_else(bad)?;
    let (h, m): (u16, u16) = (h.parse().map_err(|_| bad())?, m.parse().map_err(|_| bad())?);
    if h > 24 || m > 59 || (h == 24 && m > 0) || text.len() != 5 {
        return Err(bad());
    }
    Ok(h * 60 + m)
}

/// `+01:00`, `-05:30` as minutes.
fn offset_of(text: &str) -> Result<i16, String> {
    let bad = || format!("utc_offset = \"{text}\" is not an offset like +01:00 or -05:30");
    let (sign, rest) = match text.as_bytes().first() {
        Some(b'+') => (1, &text[1..]),
        Some(b'-') => (-1, &text[1..]),
        _ => return Err(bad()),
    };
    let m = minutes_of(rest, "utc_offset").map_err(|_| bad())?;
    if m > 14 * 60 {
        return Err(bad());
    }
    Ok(sign * m as i16)
}

impl Calendar {
    /// Validates the shifts of a topology and its offset.
    pub fn new(utc_offset: Option<&str>, raw: &[RawShift]) -> Result<Self, String> {
        let utc_offset_min = utc_offset.map(offset_of).transpose()?.unwrap_or(0);
        let mut shifts = Vec::new();
        for s in raw {
            let name = s.name.trim();
            if name.is_empty()
                || name.len() > 32
                || !name
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
            {
                return Err(format!(
                    "shift name \"{}\": 1 to 32 letters, digits, - or _",
                    crate::ids::excerpt(&s.name)
                ));
            }
            if shifts.iter().any(|o: &Shift| o.name == name) {
                return Err(format!("shift `{name}` is defined twice"));
            }
            let start = minutes_of(&s.start, &format!("shift `{name}` start"))?;
            let end = minutes_of(&s.end, &format!("shift `{name}` end"))?;
            let length = (i32::from(end) - i32::from(start)).rem_euclid(1440);
            let length = if length == 0 { 1440 } else { length };
            let mut days = Vec::new();
            for d in &s.days {
                let i = WEEKDAYS
                    .iter()
                    .position(|w| w.eq_ignore_ascii_case(d))
                    .ok_or_else(|| {
                        format!(
                            "shift `{name}`: day \"{}\" is none of {}",
                            crate::ids::excerpt(d),
                            WEEKDAYS.join(", ")
                        )
                    })?;
                days.push(i as u8);
            }
            if days.is_empty() {
                days = (0..7).collect();
            }
            shifts.push(Shift {
                name: name.to_string(),
                start_min: start % 1440,
                length_min: length as u16,
                days,
            });
        }
        Ok(Self {
            utc_offset_min,
            shifts,
        })
    }

    /// Whether there is no shift (planned busy always).
    pub fn always(&self) -> bool {
        self.shifts.is_empty()
    }

    /// The planned busy periods within `[since, until)` (ms since the
    /// Unix epoch), in time order, each cut to the range, with a label:
    /// each shift as it falls (`2026-11-25 early`), or, with no shift,
    /// each local day (`2026-11-25`).
    pub fn periods(&self, since: i64, until: i64) -> Vec<(i64, i64, String)> {
        let offset = i64::from(self.utc_offset_min) * MINUTE_MS;
        // Local midnights, from the day before `since` (a night shift
        // that began then) to the day of `until`.
        let first_day = (since + offset).div_euclid(DAY_MS) - 1;
        let last_day = (until + offset).div_euclid(DAY_MS);
        let mut out = Vec::new();
        for day in first_day..=last_day {
            let midnight = day * DAY_MS - offset;
            let date = date_of(day);
            if self.always() {
                push_cut(&mut out, midnight, midnight + DAY_MS, since, until, date);
                continue;
            }
            // 1970-01-01 was a Thursday (3 with Monday = 0).
            let weekday = (day + 3).rem_euclid(7) as u8;
            for s in self.shifts.iter().filter(|s| s.days.contains(&weekday)) {
                let start = midnight + i64::from(s.start_min) * MINUTE_MS;
                let end = start + i64::from(s.length_min) * MINUTE_MS;
                push_cut(
                    &mut out,
                    start,
                    end,
                    since,
                    until,
                    format!("{date} {}", s.name),
                );
            }
        }
        out.sort_by_key(|p| p.0);
        out
    }
}

fn push_cut(
    out: &mut Vec<(i64, i64, String)>,
    start: i64,
    end: i64,
    since: i64,
    until: i64,
    label: String,
) {
    let (s, e) = (start.max(since), end.min(until));
    if s < e {
        out.push((s, e, label));
    }
}

/// Days since 1970-01-01 as `YYYY-MM-DD`.
fn date_of(days: i64) -> String {
    let text = crate::time::utc_text(days * DAY_MS);
    text[..10].to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shift(name: &str, start: &str, end: &str, days: &[&str]) -> RawShift {
        RawShift {
            name: name.into(),
            start: start.into(),
            end: end.into(),
            days: days.iter().map(|d| d.to_string()).collect(),
        }
    }

    #[test]
    fn shifts_fall_on_their_days_in_local_time_and_a_night_shift_crosses_midnight() {
        let c = Calendar::new(
            Some("+01:00"),
            &[
                shift(
                    "early",
                    "06:00",
                    "14:00",
                    &["mon", "tue", "wed", "thu", "fri"],
                ),
                shift("night", "22:00", "06:00", &["wed"]),
            ],
        )
        .expect("valid");
        // 2026-11-25 is a Wednesday; 00:00 UTC.
        let wed = 1_795_564_800_000;
        let p = c.periods(wed, wed + DAY_MS);
        let labels: Vec<&str> = p.iter().map(|x| x.2.as_str()).collect();
        assert_eq!(labels, vec!["2026-11-25 early", "2026-11-25 night"]);
        // 06:00 local is 05:00 UTC.
        assert_eq!(p[0].0 - wed, 5 * 3_600_000);
        assert_eq!(p[0].1 - p[0].0, 8 * 3_600_000);
        // The night shift runs to 06:00 local Thursday: cut at the range.
        assert_eq!(p[1].1, wed + DAY_MS);
        let whole = c.periods(wed, wed + 2 * DAY_MS);
        assert_eq!(whole[1].1 - whole[1].0, 8 * 3_600_000);
        assert_eq!(whole.len(), 3, "{whole:?}");
    }

    #[test]
    fn no_shift_is_always_by_day_and_bad_shifts_are_refused_by_name() {
        let always = Calendar::default();
        let p = always.periods(1_000, 1_000 + DAY_MS);
        assert_eq!(p.len(), 2);
        assert_eq!(p.iter().map(|x| x.1 - x.0).sum::<i64>(), DAY_MS);
        for (offset, s, what) in [
            (None, shift("a", "25:00", "06:00", &[]), "start"),
            (None, shift("a", "06:00", "6:00", &[]), "end"),
            (None, shift("a", "06:00", "07:00", &["mo"]), "day"),
            (
                Some("1:00"),
                shift("a", "06:00", "07:00", &[]),
                "utc_offset",
            ),
            (None, shift("", "06:00", "07:00", &[]), "shift name"),
        ] {
            let e = Calendar::new(offset, &[s]).expect_err("refused");
            assert!(e.contains(what), "{e}");
        }
        let twice = [
            shift("a", "06:00", "07:00", &[]),
            shift("a", "08:00", "09:00", &[]),
        ];
        assert!(Calendar::new(None, &twice).is_err());
    }
}
