//! Logging from the cycle thread: fixed-size `Copy` records pushed into a lock-free ring
//! (no formatting, no allocation) and drained by a non-real-time thread into `tracing`.
//! A full ring drops the record and counts it.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use heapless::spsc::{Consumer, Producer, Queue};

/// Capacity of the log ring.
pub const LOG_RING_CAPACITY: usize = 1024;

/// What happened (the message text lives in [`LogCode::message`], on the draining side).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum LogCode {
    /// The cycle started; `a` = period in µs.
    Started,
    /// A new plan was adopted; `a` = plan id, `b` = policy id.
    PlanAdopted,
    /// A plan was scheduled to take over at a join index; `a` = plan id, `b` = index.
    PlanScheduled,
    /// A plan was refused (discontinuous, late, or while stopping); `a` = plan id.
    PlanRefused,
    /// A plan was completed; `a` = plan id.
    PlanFinished,
    /// The twin revoked the running plan; `a` = plan id.
    PlanRevoked,
    /// A controlled stop began; `a` = the [`crate::runtime::cycle::StopReason`] code.
    StopBegun,
    /// The arm stands still after a controlled stop.
    Stopped,
    /// The link refused a command or is lost; `a` = link error code.
    LinkError,
    /// The cycle stopped.
    Finished,
}

impl LogCode {
    /// Human-readable message.
    pub fn message(self) -> &'static str {
        match self {
            LogCode::Started => "cycle started",
            LogCode::PlanAdopted => "plan adopted",
            LogCode::PlanScheduled => "plan scheduled to take over",
            LogCode::PlanRefused => "plan refused",
            LogCode::PlanFinished => "plan finished",
            LogCode::PlanRevoked => "plan revoked by the twin",
            LogCode::StopBegun => "controlled stop begun",
            LogCode::Stopped => "arm stopped",
            LogCode::LinkError => "robot link error",
            LogCode::Finished => "cycle finished",
        }
    }
}

/// One log record.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct LogRecord {
    /// Cycle time of the event, ns.
    pub t_ns: u64,
    /// What happened.
    pub code: LogCode,
    /// First argument (see [`LogCode`]).
    pub a: f64,
    /// Second argument (see [`LogCode`]).
    pub b: f64,
}

/// The cycle's end of the ring.
pub struct RtLogger {
    tx: Producer<'static, LogRecord>,
    dropped: Arc<AtomicU64>,
}

/// The draining end of the ring.
pub struct RtLogDrain {
    rx: Consumer<'static, LogRecord>,
    dropped: Arc<AtomicU64>,
}

/// A log ring (allocated once; lives for the process).
pub fn ring() -> (RtLogger, RtLogDrain) {
    let q: &'static mut Queue<LogRecord, LOG_RING_CAPACITY> = Box::leak(Box::new(Queue::new()));
    let (tx, rx) = q.split();
    let dropped = Arc::new(AtomicU64::new(0));
    (
        RtLogger {
            tx,
            dropped: dropped.clone(),
        },
        RtLogDrain { rx, dropped },
    )
}

impl RtLogger {
    /// Records an event (wait-free; drops and counts when the ring is full).
    #[inline]
    pub fn log(&mut self, t_ns: u64, code: LogCode, a: f64, b: f64) {
        if self.tx.enqueue(LogRecord { t_ns, code, a, b }).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

impl RtLogDrain {
    /// Passes every pending record to `f`; returns how many.
    pub fn drain(&mut self, mut f: impl FnMut(&LogRecord)) -> usize {
        let mut n = 0;
        while let Some(r) = self.rx.dequeue() {
            f(&r);
            n += 1;
        }
        n
    }

    /// Records dropped because the ring was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Emits every pending record through `tracing`.
    pub fn drain_to_tracing(&mut self) -> usize {
        self.drain(|r| {
            tracing::info!(
                target: "rt_cycle",
                t_s = r.t_ns as f64 * 1e-9,
                a = r.a,
                b = r.b,
                "{}",
                r.code.message()
            );
        })
    }

    /// Spawns a thread draining into `tracing` every `period` until `stop` is set (a final
    /// drain follows).
    pub fn spawn(
        mut self,
        period: Duration,
        stop: Arc<AtomicBool>,
    ) -> std::io::Result<std::thread::JoinHandle<()>> {
        std::thread::Builder::new()
            .name("rt-log-drain".into())
            .spawn(move || {
                while !stop.load(Ordering::Acquire) {
                    self.drain_to_tracing();
                    std::thread::sleep(period);
                }
                self.drain_to_tracing();
                let d = self.dropped();
                if d > 0 {
                    tracing::warn!(dropped = d, "cycle log records were dropped (ring full)");
                }
            })
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn records_arrive_in_order_and_overflow_is_counted() {
        let (mut log, mut drain) = ring();
        for i in 0..(LOG_RING_CAPACITY + 10) {
            log.log(i as u64, LogCode::PlanAdopted, i as f64, 0.0);
        }
        let mut ts = Vec::new();
        drain.drain(|r| ts.push(r.t_ns));
        assert_eq!(ts.len(), LOG_RING_CAPACITY - 1);
        assert!(ts.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(drain.dropped(), 11);
    }
}
