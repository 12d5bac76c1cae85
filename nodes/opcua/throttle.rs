//! Failed OPC UA logins, throttled per key (sans-I/O: the clock is passed
//! in). The key is the client's address, as the gateway's front knows it
//! (`front`): a guesser slows and locks its own address, never a user name
//! for its real user logging in from elsewhere.
//!
//! - the first [`FREE_FAILURES`] failures of a key cost nothing;
//! - each further failure is answered only after a delay that doubles from
//!   [`FIRST_DELAY`] up to [`MAX_DELAY`];
//! - after [`LOCK_AFTER`] failures the key is locked for the lockout time
//!   (default [`LOCKOUT`]): every login of it is refused, the right
//!   password too, without a check (and the front refuses its
//!   connections);
//! - [`FORGET_AFTER`] without a failure forgets a key's failures; a
//!   lockout that ended allows [`FREE_FAILURES`] again. A success forgets
//!   nothing: a real user logging in now and then from the guesser's
//!   address must not wipe the guesser's count (300 guesses in 104 s went
//!   unlocked so).

use std::collections::HashMap;
use std::time::{Duration, Instant};

/// Failures of a key that cost no delay.
pub const FREE_FAILURES: u32 = 3;
/// The delay after the first failure beyond the free ones.
pub const FIRST_DELAY: Duration = Duration::from_millis(250);
/// The longest delay.
pub const MAX_DELAY: Duration = Duration::from_secs(4);
/// Failures after which a key is locked.
pub const LOCK_AFTER: u32 = 10;
/// How long a key stays locked, by default.
pub const LOCKOUT: Duration = Duration::from_secs(60);
/// A key's failures are forgotten after this long without one.
pub const FORGET_AFTER: Duration = Duration::from_secs(600);

#[derive(Debug, Clone, Copy)]
struct Failures {
    count: u32,
    last: Instant,
    locked_until: Option<Instant>,
}

/// What a login of a key may do now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Check its password.
    Check,
    /// Refuse it unchecked: the key is locked for this much longer.
    Locked(Duration),
}

/// The failures of each key.
#[derive(Debug)]
pub struct LoginThrottle {
    lockout: Duration,
    keys: HashMap<String, Failures>,
}

impl LoginThrottle {
    /// A throttle locking a key for `lockout`.
    pub fn new(lockout: Duration) -> Self {
        Self {
            lockout,
            keys: HashMap::new(),
        }
    }

    /// Before a login of `key` is checked.
    pub fn check(&mut self, now: Instant, key: &str) -> Verdict {
        self.forget_old(now);
        match self.keys.get_mut(key) {
            Some(f) => match f.locked_until {
                Some(until) if now < until => Verdict::Locked(until - now),
                Some(_) => {
                    // The lockout is over: a fresh start.
                    self.keys.remove(key);
                    Verdict::Check
                }
                None => Verdict::Check,
            },
            None => Verdict::Check,
        }
    }

    /// A login of `key` failed at `now`: its failures so far, and how long
    /// to wait before answering (zero once it locks: the answer says so).
    pub fn failed(&mut self, now: Instant, key: &str) -> (u32, Duration) {
        let f = self.keys.entry(key.to_string()).or_insert(Failures {
            count: 0,
            last: now,
            locked_until: None,
        });
        f.count += 1;
        f.last = now;
        if f.count >= LOCK_AFTER {
            f.locked_until = Some(now + self.lockout);
            return (f.count, Duration::ZERO);
        }
        let beyond = f.count.saturating_sub(FREE_FAILURES);
        let delay = if beyond == 0 {
            Duration::ZERO
        } else {
            (FIRST_DELAY * 2u32.saturating_pow(beyond - 1)).min(MAX_DELAY)
        };
        (f.count, delay)
    }

    fn forget_old(&mut self, now: Instant) {
        self.keys.retain(|_, f| {
            f.locked_until.is_some_and(|u| now < u)
                || now.saturating_duration_since(f.last) < FORGET_AFTER
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failures_are_delayed_more_and_more_then_locked_then_free_again() {
        let mut t = LoginThrottle::new(Duration::from_secs(60));
        let t0 = Instant::now();
        let delays: Vec<Duration> = (0..9)
            .map(|_| {
                assert_eq!(t.check(t0, "console"), Verdict::Check);
                t.failed(t0, "console").1
            })
            .collect();
        let ms = |v: &[u64]| {
            v.iter()
                .map(|&m| Duration::from_millis(m))
                .collect::<Vec<_>>()
        };
        assert_eq!(delays, ms(&[0, 0, 0, 250, 500, 1000, 2000, 4000, 4000]));
        assert_eq!(t.failed(t0, "console"), (10, Duration::ZERO));
        // Locked: refused unchecked, whatever the password.
        assert_eq!(
            t.check(t0 + Duration::from_secs(1), "console"),
            Verdict::Locked(Duration::from_secs(59))
        );
        // Another user is not locked.
        assert_eq!(t.check(t0, "observer"), Verdict::Check);
        // After the lockout: checked again, the free failures again.
        assert_eq!(
            t.check(t0 + Duration::from_secs(60), "console"),
            Verdict::Check
        );
        assert_eq!(
            t.failed(t0 + Duration::from_secs(60), "console").1,
            Duration::ZERO
        );
        // A success forgets nothing: a guesser's count goes on while the
        // real user logs in now and then.
        assert_eq!(t.failed(t0 + Duration::from_secs(61), "console").0, 2);
        // Old failures are forgotten.
        for _ in 0..5 {
            t.failed(t0, "observer");
        }
        t.check(t0 + FORGET_AFTER, "x");
        assert_eq!(t.failed(t0 + FORGET_AFTER, "observer").0, 1);
    }
}
