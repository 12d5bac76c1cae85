//! Waiting in the multi-process tests: a condition polled until it holds,
//! within a limit whose end fails the test with what was asked for and what
//! was last seen instead. Tests wait on what they can observe (a status, a
//! log line, a process gone), never for a fixed time; a sleep left in a test
//! is a fault's duration, a pace, or a window in which something must not
//! happen.

use std::fmt::Debug;
use std::future::Future;
use std::time::{Duration, Instant};

/// How often a condition is looked at.
pub const POLL: Duration = Duration::from_millis(50);

/// Looks at `check` every [`POLL`] until it gives `Ok`, whose value is
/// returned. `Err` is what it saw instead; once `limit` passed, the test
/// fails with `what` and the last of them.
pub fn wait_until<T, E: Debug>(
    what: &str,
    limit: Duration,
    check: impl FnMut() -> Result<T, E>,
) -> T {
    poll_until(POLL, limit, check)
        .unwrap_or_else(|seen| panic!("{what}: not within {limit:?}; last seen: {seen:?}"))
}

/// Looks at `check` every `every` until it gives `Ok`; after `limit`, the
/// last `Err` (for a caller that reports rather than fails, or one that
/// must not panic, as in a `Drop`).
pub fn poll_until<T, E>(
    every: Duration,
    limit: Duration,
    mut check: impl FnMut() -> Result<T, E>,
) -> Result<T, E> {
    let end = Instant::now() + limit;
    loop {
        match check() {
            Ok(v) => return Ok(v),
            Err(seen) if Instant::now() >= end => return Err(seen),
            Err(_) => std::thread::sleep(every),
        }
    }
}

/// [`wait_until`] in an async test: `check` is awaited, and the task sleeps
/// between looks.
pub async fn wait_until_async<T, E: Debug, F: Future<Output = Result<T, E>>>(
    what: &str,
    limit: Duration,
    mut check: impl FnMut() -> F,
) -> T {
    let end = Instant::now() + limit;
    loop {
        match check().await {
            Ok(v) => return v,
            Err(seen) if Instant::now() >= end => {
                panic!("{what}: not within {limit:?}; last seen: {seen:?}")
            }
            Err(_) => tokio::time::sleep(POLL).await,
        }
    }
}

/// `Ok(())` if `holds`, else `Err(seen)`: a condition for [`wait_until`]
/// from a test and what to show when it does not hold (boxed: a status is
/// large).
pub fn holds<E>(holds: bool, seen: impl FnOnce() -> E) -> Result<(), Box<E>> {
    if holds {
        Ok(())
    } else {
        Err(Box::new(seen()))
    }
}
