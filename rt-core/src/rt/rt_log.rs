//! Logging from the cycle thread: typed, fixed-size `Copy` events (the cycle's
//! `CycleEvent`) pushed into a lock-free ring (no formatting, no allocation) and drained by
//! a non-real-time thread into `tracing`.
//! A full ring drops the record and counts it.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use heapless::spsc::{Consumer, Producer, Queue};

/// Capacity of the log ring.
pub const LOG_RING_CAPACITY: usize = 1024;

/// One log record: when, and a typed, `Copy` event (the thread that drains formats it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LogRecord<E> {
    /// Cycle time of the event, ns.
    pub t_ns: u64,
    /// What happened.
    pub event: E,
}

/// The cycle's end of the ring.
pub struct RtLogger<E: 'static> {
    tx: Producer<'static, LogRecord<E>>,
    dropped: Arc<AtomicU64>,
}

/// The draining end of the ring.
pub struct RtLogDrain<E: 'static> {
    rx: Consumer<'static, LogRecord<E>>,
    dropped: Arc<AtomicU64>,
}

/// A log ring (allocated once; lives for the process).
pub fn ring<E: Copy + Send + 'static>() -> (RtLogger<E>, RtLogDrain<E>) {
    let q: &'static mut Queue<LogRecord<E>, LOG_RING_CAPACITY> = Box::leak(Box::new(Queue::new()));
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

impl<E: Copy> RtLogger<E> {
    /// Records an event (wait-free; drops and counts when the ring is full).
    #[inline]
    pub fn log(&mut self, t_ns: u64, event: E) {
        if self.tx.enqueue(LogRecord { t_ns, event }).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// One record to `tracing` (target `rt_cycle`).
fn trace<E: std::fmt::Debug>(r: &LogRecord<E>) {
    tracing::info!(
        target: "rt_cycle",
        t_s = r.t_ns as f64 * 1e-9,
        event = ?r.event,
        "cycle event"
    );
}

impl<E: Copy + Send + std::fmt::Debug + 'static> RtLogDrain<E> {
    /// Passes every pending record to `f`; returns how many.
    pub fn drain(&mut self, mut f: impl FnMut(&LogRecord<E>)) -> usize {
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

    /// Spawns a thread draining into `tracing` every `period` until `stop` is set (a final
    /// drain follows).
    pub fn spawn(
        self,
        period: Duration,
        stop: Arc<AtomicBool>,
    ) -> std::io::Result<std::thread::JoinHandle<()>> {
        self.spawn_observed(period, stop, |_| {})
    }

    /// [`RtLogDrain::spawn`], also passing every record to `observe` (on the drain's
    /// thread, after it went to `tracing`).
    // The drain is a non-real-time thread: it sleeps between drains.
    #[allow(clippy::disallowed_methods)]
    pub fn spawn_observed(
        mut self,
        period: Duration,
        stop: Arc<AtomicBool>,
        mut observe: impl FnMut(&LogRecord<E>) + Send + 'static,
    ) -> std::io::Result<std::thread::JoinHandle<()>> {
        let mut drain = move |d: &mut Self| {
            d.drain(|r| {
                trace(r);
                observe(r);
            })
        };
        std::thread::Builder::new()
            .name("rt-log-drain".into())
            .spawn(move || {
                while !stop.load(Ordering::Acquire) {
                    drain(&mut self);
                    std::thread::sleep(period);
                }
                drain(&mut self);
                let d = self.dropped();
                if d > 0 {
                    tracing::warn!(dropped = d, "cycle log records were dropped (ring full)");
                }
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_arrive_in_order_and_overflow_is_counted() {
        let (mut log, mut drain) = ring::<u64>();
        for i in 0..(LOG_RING_CAPACITY + 10) {
            log.log(i as u64, i as u64);
        }
        let mut ts = Vec::new();
        drain.drain(|r| ts.push(r.t_ns));
        assert_eq!(ts.len(), LOG_RING_CAPACITY - 1);
        assert!(ts.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(drain.dropped(), 11);
    }
}
