//! The hand-off between `perception run`'s capture thread and its detector: a small bounded
//! queue (a mutex and a condition variable) that either drops the **oldest** waiting frame
//! when a newer one arrives and the queue is full ([`WhenBusy::DropOldest`], live cameras:
//! the detector always gets the newest frame), or makes the capture wait for room
//! ([`WhenBusy::Wait`], finite sources: every frame is processed).
//!
//! Either side closes its end when it stops (also when it unwinds: [`ProducerGuard`],
//! [`ConsumerGuard`]): a closed producer lets the consumer take what is still queued and
//! then see the end; a closed consumer wakes a capture waiting for room or pacing, which
//! then ends. Nothing here blocks without a way out.
//!
//! ```
//! use std::time::Duration;
//! use perception::handoff::{Handoff, Popped};
//! use perception::source::WhenBusy;
//! let h = Handoff::new(1, WhenBusy::DropOldest);
//! assert_eq!(h.push(1), Ok(0));
//! assert_eq!(h.push(2), Ok(1)); // the detector was busy: frame 1 is dropped
//! assert_eq!(h.pop(Duration::ZERO), Popped::Item(2));
//! h.close_producer();
//! assert_eq!(h.pop(Duration::ZERO), Popped::Ended);
//! assert_eq!(h.dropped(), 1);
//! ```

use std::collections::VecDeque;
use std::sync::{Condvar, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

pub use crate::source::WhenBusy;

/// What [`Handoff::pop`] gave.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Popped<T> {
    /// The oldest item still waiting (with capacity 1 and [`WhenBusy::DropOldest`]: the
    /// newest frame captured).
    Item(T),
    /// Nothing arrived within the time-out; the producer goes on.
    Empty,
    /// The producer has closed and nothing is left.
    Ended,
}

#[derive(Debug)]
struct State<T> {
    queue: VecDeque<T>,
    producer_closed: bool,
    consumer_closed: bool,
    dropped: u64,
}

/// A bounded single-producer, single-consumer hand-off with a policy for a full queue.
#[derive(Debug)]
pub struct Handoff<T> {
    state: Mutex<State<T>>,
    changed: Condvar,
    capacity: usize,
    policy: WhenBusy,
}

impl<T> Handoff<T> {
    /// A hand-off holding at most `capacity` (at least 1) items, full-queue policy `policy`.
    pub fn new(capacity: usize, policy: WhenBusy) -> Self {
        Self {
            state: Mutex::new(State {
                queue: VecDeque::with_capacity(capacity.max(1)),
                producer_closed: false,
                consumer_closed: false,
                dropped: 0,
            }),
            changed: Condvar::new(),
            capacity: capacity.max(1),
            policy,
        }
    }

    /// The policy for a full queue.
    pub fn policy(&self) -> WhenBusy {
        self.policy
    }

    /// The lock; a panic on the other side (caught by its guard) does not poison the
    /// counters for this one.
    fn lock(&self) -> MutexGuard<'_, State<T>> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Producer: hands `item` over. A full queue drops its oldest items
    /// ([`WhenBusy::DropOldest`]) or waits for room ([`WhenBusy::Wait`]).
    ///
    /// # Errors
    /// The item back when the consumer has closed (before or while waiting for room).
    pub fn push(&self, item: T) -> Result<u64, T> {
        let mut s = self.lock();
        let mut dropped_now = 0;
        loop {
            if s.consumer_closed {
                return Err(item);
            }
            if s.queue.len() < self.capacity {
                break;
            }
            match self.policy {
                WhenBusy::DropOldest => {
                    s.queue.pop_front();
                    s.dropped += 1;
                    dropped_now += 1;
                }
                WhenBusy::Wait => {
                    s = self.changed.wait(s).unwrap_or_else(PoisonError::into_inner);
                }
            }
        }
        s.queue.push_back(item);
        drop(s);
        self.changed.notify_all();
        Ok(dropped_now)
    }

    /// Consumer: the oldest waiting item, waiting up to `timeout` for one.
    pub fn pop(&self, timeout: Duration) -> Popped<T> {
        let deadline = Instant::now() + timeout;
        let mut s = self.lock();
        loop {
            if let Some(item) = s.queue.pop_front() {
                drop(s);
                self.changed.notify_all(); // room for a waiting producer
                return Popped::Item(item);
            }
            if s.producer_closed {
                return Popped::Ended;
            }
            let now = Instant::now();
            if now >= deadline {
                return Popped::Empty;
            }
            s = self
                .changed
                .wait_timeout(s, deadline - now)
                .unwrap_or_else(PoisonError::into_inner)
                .0;
        }
    }

    /// Producer: waits until `until` (pacing); false at once when the consumer has closed.
    pub fn sleep_until(&self, until: Instant) -> bool {
        let mut s = self.lock();
        loop {
            if s.consumer_closed {
                return false;
            }
            let now = Instant::now();
            if now >= until {
                return true;
            }
            s = self
                .changed
                .wait_timeout(s, until - now)
                .unwrap_or_else(PoisonError::into_inner)
                .0;
        }
    }

    /// Producer: no more items.
    pub fn close_producer(&self) {
        self.lock().producer_closed = true;
        self.changed.notify_all();
    }

    /// Consumer: no more items wanted; what is still queued is discarded (not counted as
    /// dropped) and a producer waiting for room or pacing returns.
    pub fn close_consumer(&self) {
        let mut s = self.lock();
        s.consumer_closed = true;
        s.queue.clear();
        drop(s);
        self.changed.notify_all();
    }

    /// Whether the consumer has closed.
    pub fn consumer_closed(&self) -> bool {
        self.lock().consumer_closed
    }

    /// Items dropped because the queue was full ([`WhenBusy::DropOldest`]), in total.
    pub fn dropped(&self) -> u64 {
        self.lock().dropped
    }
}

/// Closes the producer's end when dropped (also on a panic in the source).
#[derive(Debug)]
pub struct ProducerGuard<'a, T>(pub &'a Handoff<T>);

impl<T> Drop for ProducerGuard<'_, T> {
    fn drop(&mut self) {
        self.0.close_producer();
    }
}

/// Closes the consumer's end when dropped (also on a panic in the detector), so the
/// capture thread never waits forever.
#[derive(Debug)]
pub struct ConsumerGuard<'a, T>(pub &'a Handoff<T>);

impl<T> Drop for ConsumerGuard<'_, T> {
    fn drop(&mut self) {
        self.0.close_consumer();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn a_full_drop_oldest_queue_keeps_the_newest_items() {
        let h = Handoff::new(2, WhenBusy::DropOldest);
        for i in 1..=5 {
            h.push(i).unwrap();
        }
        assert_eq!(h.dropped(), 3, "1, 2 and 3 dropped");
        assert_eq!(h.pop(Duration::ZERO), Popped::Item(4));
        assert_eq!(h.pop(Duration::ZERO), Popped::Item(5));
        assert_eq!(h.pop(Duration::from_millis(5)), Popped::Empty);
        h.close_producer();
        assert_eq!(h.pop(Duration::from_secs(5)), Popped::Ended);
    }

    #[test]
    fn a_waiting_producer_loses_nothing_and_is_released_by_the_consumer_closing() {
        let h = Arc::new(Handoff::new(1, WhenBusy::Wait));
        let p = {
            let h = h.clone();
            std::thread::spawn(move || {
                let _guard = ProducerGuard(&*h);
                for i in 1..=20 {
                    h.push(i).unwrap();
                }
            })
        };
        let mut got = Vec::new();
        loop {
            match h.pop(Duration::from_millis(50)) {
                Popped::Item(i) => got.push(i),
                Popped::Empty => {}
                Popped::Ended => break,
            }
        }
        p.join().unwrap();
        assert_eq!(got, (1..=20).collect::<Vec<_>>());
        assert_eq!(h.dropped(), 0);

        // A producer blocked on a full queue returns its item when the consumer goes.
        let h = Arc::new(Handoff::new(1, WhenBusy::Wait));
        h.push(1).unwrap();
        let p = {
            let h = h.clone();
            std::thread::spawn(move || h.push(2))
        };
        std::thread::sleep(Duration::from_millis(20));
        h.close_consumer();
        assert_eq!(p.join().unwrap(), Err(2));
        // Pacing ends at once too.
        let t = Instant::now();
        assert!(!h.sleep_until(Instant::now() + Duration::from_secs(30)));
        assert!(t.elapsed() < Duration::from_secs(1));
    }
}
