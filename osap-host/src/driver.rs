//! The loop that drives a runtime on tokio: the same for a host's runtime
//! and for each simulated module's.
//!
//! It takes every pending command, polls, and then sleeps until a command
//! comes, something wakes it (a link or a port has news), or the poll's
//! deadline passes; never on a timer tick. The `select!` is biased (commands
//! first, then wake-ups, then the deadline), so with tokio's clock paused a
//! run is the same every time.

use std::ops::ControlFlow;
use tokio::sync::{mpsc, Notify};
use tokio::time::Instant;

/// Polls in a row with a deadline already due before the loop waits for
/// the next timer tick.
const DUE_SPINS: u32 = 16;

/// What one poll of a driven runtime asks of the loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PollOutcome {
    /// Work is left that the poll's budget did not cover: poll again after
    /// letting other tasks run.
    pub more: bool,
    /// When to poll again if nothing else comes first.
    pub wake_at: Option<Instant>,
}

/// A runtime and what goes with it (ports, links, hardware), as [`drive`]
/// runs it.
pub trait Driven {
    /// What other tasks ask of it.
    type Command;

    /// Carries out one command; `Break` ends the loop.
    fn handle(&mut self, command: Self::Command) -> ControlFlow<()>;

    /// Polls the runtime once, now.
    fn poll(&mut self) -> PollOutcome;
}

/// Runs `driven` until a command breaks the loop or every command sender is
/// gone.
pub async fn drive<D: Driven>(
    driven: &mut D,
    commands: &mut mpsc::UnboundedReceiver<D::Command>,
    wake: &Notify,
) {
    // Polls in a row that left a deadline already due.
    let mut due_in_a_row = 0u32;
    loop {
        // Take every pending command before polling, so a send issued just
        // now goes out in this pass.
        loop {
            match commands.try_recv() {
                Ok(c) => {
                    if driven.handle(c).is_break() {
                        return;
                    }
                }
                Err(mpsc::error::TryRecvError::Empty) => break,
                Err(mpsc::error::TryRecvError::Disconnected) => return,
            }
        }
        let outcome = driven.poll();
        if outcome.more {
            tokio::task::yield_now().await;
            continue;
        }
        // A deadline already due is polled again at once, but not for ever:
        // a clock that maps its µs to instants with rounding may keep
        // reporting one, and with tokio's clock paused such a spin would
        // keep time from ever advancing. After a few, it waits for the next
        // timer tick.
        let now = Instant::now();
        let deadline = match outcome.wake_at {
            Some(t) if t <= now => {
                due_in_a_row += 1;
                if due_in_a_row < DUE_SPINS {
                    tokio::task::yield_now().await;
                    continue;
                }
                Some(now + std::time::Duration::from_micros(1))
            }
            other => other,
        };
        due_in_a_row = 0;
        let notified = wake.notified();
        tokio::select! {
            biased;
            command = commands.recv() => match command {
                Some(c) => {
                    if driven.handle(c).is_break() {
                        return;
                    }
                }
                None => return,
            },
            _ = notified => {}
            _ = sleep_until(deadline) => {}
        }
    }
}

async fn sleep_until(deadline: Option<Instant>) {
    match deadline {
        Some(t) => tokio::time::sleep_until(t).await,
        None => std::future::pending().await,
    }
}
