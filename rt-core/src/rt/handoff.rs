//! Lock-free hand-overs between the non-real-time side and the cycle thread.
//!
//! - [`channel`]: boxed values (plans, policies) prepared and validated off the cycle, handed
//!   over through a `heapless::spsc` queue — taking one is a single atomic step on the
//!   receiving side — and **returned** through a second queue so that the sending side, never
//!   the cycle, frees them.
//! - [`latest`]: `Copy` values (scene snapshots, cycle reports) through a bounded lock-free
//!   queue whose consumer keeps the newest; a full queue drops its *oldest* value and counts
//!   it (`crossbeam_queue::ArrayQueue::force_push`), so after a stall of the consumer the
//!   next read is the newest value sent, never one from the start of the stall (issue 41).
//!
//! Storage is allocated once, when a channel is made (its queues live for the rest of the
//! process: a runtime makes a handful of channels at start-up); sending and taking allocate
//! nothing. Producer and consumer roles are enforced by the borrow checker
//! (`heapless::spsc::Queue::split`; a latest-value channel's ends are not `Clone`).

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use crossbeam_queue::ArrayQueue;
use heapless::spsc::{Consumer, Producer, Queue};

/// Storage of a boxed channel's queue: up to `BOX_QUEUE_CAPACITY - 1` values in flight.
pub const BOX_QUEUE_CAPACITY: usize = 8;
/// Storage of a boxed channel's return queue (`- 1` values).
pub const RETURN_QUEUE_CAPACITY: usize = 32;

/// Sending side of a boxed hand-over (non-real-time).
pub struct BoxSender<T: 'static> {
    tx: Producer<'static, Box<T>>,
    returned: Consumer<'static, Box<T>>,
    leaked: Arc<AtomicU64>,
}

/// Receiving side of a boxed hand-over (the cycle): takes and returns without freeing.
pub struct BoxReceiver<T: 'static> {
    rx: Consumer<'static, Box<T>>,
    ret: Producer<'static, Box<T>>,
    leaked: Arc<AtomicU64>,
}

/// The send was refused because the queue is full; the value comes back.
#[derive(Debug, thiserror::Error)]
#[error("hand-over queue full")]
pub struct HandoffFull<T>(pub Box<T>);

/// A boxed hand-over: see the module docs.
pub fn channel<T: Send + 'static>() -> (BoxSender<T>, BoxReceiver<T>) {
    let fwd: &'static mut Queue<Box<T>, BOX_QUEUE_CAPACITY> = Box::leak(Box::new(Queue::new()));
    let back: &'static mut Queue<Box<T>, RETURN_QUEUE_CAPACITY> = Box::leak(Box::new(Queue::new()));
    let (tx, rx) = fwd.split();
    let (ret, returned) = back.split();
    let leaked = Arc::new(AtomicU64::new(0));
    (
        BoxSender {
            tx,
            returned,
            leaked: leaked.clone(),
        },
        BoxReceiver { rx, ret, leaked },
    )
}

impl<T: Send + 'static> BoxSender<T> {
    /// Hands `value` over; frees whatever the receiver has returned first.
    ///
    /// # Errors
    /// [`HandoffFull`] when the receiver has not taken the earlier values.
    pub fn send(&mut self, value: Box<T>) -> Result<(), HandoffFull<T>> {
        self.collect_returned();
        self.tx.enqueue(value).map_err(HandoffFull)
    }

    /// Frees the values the receiver has returned; returns how many.
    pub fn collect_returned(&mut self) -> usize {
        self.collect_returned_with(|_| {})
    }

    /// Frees the values the receiver has returned, showing each to `seen` first (which
    /// values the receiver no longer holds); returns how many.
    pub fn collect_returned_with(&mut self, mut seen: impl FnMut(&T)) -> usize {
        let mut n = 0;
        while let Some(v) = self.returned.dequeue() {
            seen(&v);
            drop(v);
            n += 1;
        }
        n
    }

    /// Values the receiver could not return (its return queue was full) and had to leak
    /// rather than free on the real-time thread.
    pub fn leaked(&self) -> u64 {
        self.leaked.load(Ordering::Relaxed)
    }
}

impl<T: Send + 'static> BoxReceiver<T> {
    /// Takes the oldest value sent, if any (one atomic step; no allocation, no free).
    pub fn take(&mut self) -> Option<Box<T>> {
        self.rx.dequeue()
    }

    /// Takes the newest value sent, returning any older ones to the sender.
    pub fn take_latest(&mut self) -> Option<Box<T>> {
        let mut latest = self.rx.dequeue()?;
        while let Some(newer) = self.rx.dequeue() {
            let old = std::mem::replace(&mut latest, newer);
            self.give_back(old);
        }
        Some(latest)
    }

    /// Returns a value to the sender for freeing. Never frees here: when the return queue is
    /// full the value is leaked and counted.
    pub fn give_back(&mut self, value: Box<T>) {
        if let Err(v) = self.ret.enqueue(value) {
            std::mem::forget(v);
            self.leaked.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// Producer of a latest-value channel.
pub struct LatestSender<T: Copy + 'static> {
    queue: Arc<ArrayQueue<T>>,
    dropped: Arc<AtomicU64>,
}

/// Consumer of a latest-value channel.
pub struct LatestReceiver<T: Copy + 'static> {
    queue: Arc<ArrayQueue<T>>,
}

/// Storage of a latest-value channel: up to `LATEST_CAPACITY` values queued.
pub const LATEST_CAPACITY: usize = 64;

/// A latest-value channel: see the module docs.
pub fn latest<T: Copy + Send + 'static>() -> (LatestSender<T>, LatestReceiver<T>) {
    let queue = Arc::new(ArrayQueue::new(LATEST_CAPACITY));
    (
        LatestSender {
            queue: queue.clone(),
            dropped: Arc::new(AtomicU64::new(0)),
        },
        LatestReceiver { queue },
    )
}

impl<T: Copy + Send + 'static> LatestSender<T> {
    /// Sends `value`, always queued; when the queue is full its oldest value is dropped
    /// and counted. Returns whether none was dropped.
    pub fn send(&mut self, value: T) -> bool {
        if self.queue.force_push(value).is_none() {
            true
        } else {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            false
        }
    }

    /// Values dropped (the oldest) because the queue was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

impl<T: Copy + Send + 'static> LatestReceiver<T> {
    /// The newest value queued since the last call, if any.
    pub fn latest(&mut self) -> Option<T> {
        let mut last = None;
        while let Some(v) = self.queue.pop() {
            last = Some(v);
        }
        last
    }

    /// Every value queued since the last call and still held, oldest first.
    pub fn drain(&mut self, mut f: impl FnMut(T)) {
        while let Some(v) = self.queue.pop() {
            f(v);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicUsize;

    struct Counted(Arc<AtomicUsize>);
    impl Drop for Counted {
        fn drop(&mut self) {
            self.0.fetch_add(1, Ordering::SeqCst);
        }
    }

    #[test]
    fn values_are_freed_by_the_sender_never_by_the_receiver() {
        let drops = Arc::new(AtomicUsize::new(0));
        let (mut tx, mut rx) = channel::<Counted>();
        for _ in 0..3 {
            assert!(tx.send(Box::new(Counted(drops.clone()))).is_ok());
        }
        let newest = rx.take_latest();
        assert!(newest.is_some());
        assert_eq!(drops.load(Ordering::SeqCst), 0, "receiver freed a value");
        if let Some(v) = newest {
            rx.give_back(v);
        }
        assert_eq!(drops.load(Ordering::SeqCst), 0);
        assert_eq!(tx.collect_returned(), 3);
        assert_eq!(drops.load(Ordering::SeqCst), 3);
        assert_eq!(tx.leaked(), 0);
    }

    #[test]
    fn a_full_queue_refuses_and_gives_the_value_back() {
        let (mut tx, _rx) = channel::<u32>();
        for i in 0..(BOX_QUEUE_CAPACITY - 1) as u32 {
            assert!(tx.send(Box::new(i)).is_ok());
        }
        match tx.send(Box::new(99)) {
            Err(HandoffFull(v)) => assert_eq!(*v, 99),
            Ok(()) => panic!("a full queue accepted a value"),
        }
    }

    /// Issue 41: a full queue drops its oldest value, never the newest. Before, the newest
    /// were dropped: after a stall of the consumer longer than the queue, its next read was
    /// a value from the start of the stall (here `LATEST_CAPACITY - 2` of
    /// `LATEST_CAPACITY + 4`).
    #[test]
    fn latest_keeps_the_newest_when_full_and_counts_drops() {
        let (mut tx, mut rx) = latest::<u64>();
        assert_eq!(rx.latest(), None);
        let newest = LATEST_CAPACITY as u64 + 4;
        for i in 0..=newest {
            tx.send(i);
        }
        assert_eq!(tx.dropped(), 5);
        assert_eq!(rx.latest(), Some(newest));
        assert_eq!(rx.latest(), None);
        // And what is left to drain after a stall is the newest values, in order.
        for i in 0..=newest {
            tx.send(i);
        }
        let mut seen = Vec::new();
        rx.drain(|v| seen.push(v));
        assert_eq!(seen.len(), LATEST_CAPACITY);
        assert_eq!(seen.last(), Some(&newest));
        assert!(seen.windows(2).all(|w| w[1] == w[0] + 1));
    }

    #[test]
    fn hand_over_across_threads_preserves_order() {
        let (mut tx, mut rx) = channel::<u64>();
        let consumer = std::thread::spawn(move || {
            let mut seen = Vec::new();
            while seen.len() < 1000 {
                if let Some(v) = rx.take() {
                    seen.push(*v);
                    rx.give_back(v);
                }
            }
            seen
        });
        let mut i = 0;
        while i < 1000 {
            if tx.send(Box::new(i)).is_ok() {
                i += 1;
            }
        }
        let seen = consumer.join().unwrap_or_default();
        assert_eq!(seen, (0..1000).collect::<Vec<_>>());
    }
}
