//! A request lane: a task that carries out a node's jobs one at a time, in
//! the order given, and sends each outcome back, so that the node's loop
//! never waits on another station. The cell keeps one lane per station, the
//! operator one to its cell.

use std::future::Future;
use tokio::sync::mpsc::{unbounded_channel, UnboundedSender};

/// Starts a lane: each job sent to the returned sender is carried out by
/// `run`, one at a time, and its outcome sent to `outcomes`. The lane ends
/// when the sender is dropped or `outcomes` is closed.
pub fn spawn<J, R, F, Fut>(outcomes: UnboundedSender<R>, mut run: F) -> UnboundedSender<J>
where
    J: Send + 'static,
    R: Send + 'static,
    F: FnMut(J) -> Fut + Send + 'static,
    Fut: Future<Output = R> + Send,
{
    let (jobs, mut rx) = unbounded_channel();
    tokio::spawn(async move {
        while let Some(job) = rx.recv().await {
            if outcomes.send(run(job).await).is_err() {
                break;
            }
        }
    });
    jobs
}
