//! A single-producer single-consumer byte queue between two priority levels, lock-free
//! with atomics.
//!
//! The producer writes `head`, the consumer writes `tail`; each reads the other's index
//! with acquire ordering and publishes its own with release ordering, so a byte is fully
//! written before the consumer can see it. One slot stays empty to tell full from empty.
//! A byte pushed into a full queue is dropped and counted; [`ByteRing::push_all`] queues a
//! whole frame or none of it.

use core::sync::atomic::{AtomicU8, AtomicU32, AtomicUsize, Ordering};

/// A queue of `N - 1` bytes.
pub struct ByteRing<const N: usize> {
    buf: [AtomicU8; N],
    head: AtomicUsize,
    tail: AtomicUsize,
    dropped: AtomicU32,
}

impl<const N: usize> ByteRing<N> {
    /// An empty queue.
    pub const fn new() -> Self {
        Self {
            buf: [const { AtomicU8::new(0) }; N],
            head: AtomicUsize::new(0),
            tail: AtomicUsize::new(0),
            dropped: AtomicU32::new(0),
        }
    }

    /// Producer side: appends `b`, or counts it dropped if the queue is full.
    pub fn push(&self, b: u8) {
        let head = self.head.load(Ordering::Relaxed);
        let next = (head + 1) % N;
        if next == self.tail.load(Ordering::Acquire) {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            return;
        }
        self.buf[head].store(b, Ordering::Relaxed);
        self.head.store(next, Ordering::Release);
    }

    /// Producer side: appends all of `bytes` if they fit, else nothing (counted as one
    /// drop). Returns whether they were queued.
    pub fn push_all(&self, bytes: &[u8]) -> bool {
        let head = self.head.load(Ordering::Relaxed);
        let tail = self.tail.load(Ordering::Acquire);
        let used = (head + N - tail) % N;
        if used + bytes.len() > N - 1 {
            self.dropped.fetch_add(1, Ordering::Relaxed);
            return false;
        }
        let mut at = head;
        for &b in bytes {
            self.buf[at].store(b, Ordering::Relaxed);
            at = (at + 1) % N;
        }
        self.head.store(at, Ordering::Release);
        true
    }

    /// Consumer side: the oldest byte.
    pub fn pop(&self) -> Option<u8> {
        let tail = self.tail.load(Ordering::Relaxed);
        if tail == self.head.load(Ordering::Acquire) {
            return None;
        }
        let b = self.buf[tail].load(Ordering::Relaxed);
        self.tail.store((tail + 1) % N, Ordering::Release);
        Some(b)
    }

    /// Whether no byte is waiting.
    pub fn is_empty(&self) -> bool {
        self.tail.load(Ordering::Relaxed) == self.head.load(Ordering::Acquire)
    }

    /// Drops (bytes by [`ByteRing::push`], frames by [`ByteRing::push_all`]) since the
    /// last call.
    pub fn take_dropped(&self) -> u32 {
        self.dropped.swap(0, Ordering::Relaxed)
    }
}
