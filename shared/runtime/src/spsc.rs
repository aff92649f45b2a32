//! A bounded single-producer, single-consumer queue of plain-data values,
//! for handing samples from a polling thread to a worker thread.
//!
//! A value is copied once, into its slot, and read in place; neither side
//! allocates, locks or makes a system call, and a full queue refuses the
//! value instead of waiting (the producer decides what a refusal means).
//! Slots are allocated once and touched only when first used.

use std::cell::UnsafeCell;
use std::mem::MaybeUninit;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

struct Ring<T> {
    slots: Box<[UnsafeCell<MaybeUninit<T>>]>,
    /// Values read so far (written by the consumer only).
    head: AtomicUsize,
    /// Values written so far (written by the producer only).
    tail: AtomicUsize,
}

// SAFETY: a slot is written only by the producer while it is free (not
// between head and tail) and read only by the consumer while it is full;
// the Release stores and Acquire loads of head and tail order those
// accesses, so no slot is accessed by both threads at once.
unsafe impl<T: Send> Sync for Ring<T> {}

/// The writing end; one per queue (not `Clone`).
pub struct Producer<T> {
    ring: Arc<Ring<T>>,
}

/// The reading end; one per queue (not `Clone`).
pub struct Consumer<T> {
    ring: Arc<Ring<T>>,
}

/// A queue of `capacity` values (at least 1).
pub fn channel<T: Copy + Send>(capacity: usize) -> (Producer<T>, Consumer<T>) {
    let capacity = capacity.max(1);
    let slots = (0..capacity)
        .map(|_| UnsafeCell::new(MaybeUninit::uninit()))
        .collect();
    let ring = Arc::new(Ring {
        slots,
        head: AtomicUsize::new(0),
        tail: AtomicUsize::new(0),
    });
    (Producer { ring: ring.clone() }, Consumer { ring })
}

impl<T: Copy> Producer<T> {
    /// Copies `value` into the queue; `false` if the queue is full.
    pub fn push(&mut self, value: &T) -> bool {
        let ring = &*self.ring;
        let tail = ring.tail.load(Ordering::Relaxed);
        let head = ring.head.load(Ordering::Acquire);
        if tail - head == ring.slots.len() {
            return false;
        }
        let slot = ring.slots[tail % ring.slots.len()].get();
        // SAFETY: the slot is free (the consumer is done with it: head has
        // passed it, Acquire above), and only this producer writes slots.
        // One copy, straight into the slot.
        unsafe { std::ptr::copy_nonoverlapping(value, (*slot).as_mut_ptr(), 1) };
        ring.tail.store(tail + 1, Ordering::Release);
        true
    }
}

impl<T: Copy> Consumer<T> {
    /// Calls `read` with the oldest value, then frees its slot; `None` if
    /// the queue is empty.
    pub fn pop_with<R>(&mut self, read: impl FnOnce(&T) -> R) -> Option<R> {
        let ring = &*self.ring;
        let head = ring.head.load(Ordering::Relaxed);
        let tail = ring.tail.load(Ordering::Acquire);
        if head == tail {
            return None;
        }
        let slot = ring.slots[head % ring.slots.len()].get();
        // SAFETY: the slot is full (tail has passed it, Acquire above), so it
        // was initialised, and the producer does not touch it until head
        // moves past it below.
        let result = read(unsafe { (*slot).assume_init_ref() });
        ring.head.store(head + 1, Ordering::Release);
        Some(result)
    }

    /// Values waiting.
    pub fn len(&self) -> usize {
        let ring = &*self.ring;
        ring.tail.load(Ordering::Acquire) - ring.head.load(Ordering::Relaxed)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_come_out_in_order_and_a_full_queue_refuses() {
        let (mut tx, mut rx) = channel::<[u64; 4]>(3);
        assert!(rx.pop_with(|v| *v).is_none());
        for i in 0..3 {
            assert!(tx.push(&[i; 4]));
        }
        assert!(!tx.push(&[9; 4]), "full");
        assert_eq!(rx.len(), 3);
        assert_eq!(rx.pop_with(|v| v[0]), Some(0));
        assert!(tx.push(&[3; 4]), "a slot is free again");
        let rest: Vec<u64> = std::iter::from_fn(|| rx.pop_with(|v| v[3])).collect();
        assert_eq!(rest, vec![1, 2, 3]);
        assert!(rx.is_empty());
    }

    #[test]
    fn every_value_crosses_threads_once() {
        const N: u64 = 200_000;
        let (mut tx, mut rx) = channel::<(u64, u64)>(64);
        let producer = std::thread::spawn(move || {
            let mut refused = 0u64;
            for i in 0..N {
                // Bounded: the consumer drains concurrently.
                while !tx.push(&(i, i * 3)) {
                    refused += 1;
                    std::thread::yield_now();
                }
            }
            refused
        });
        let mut next = 0;
        let since = std::time::Instant::now();
        while next < N {
            assert!(since.elapsed() < std::time::Duration::from_secs(60));
            match rx.pop_with(|v| *v) {
                Some((i, j)) => {
                    assert_eq!((i, j), (next, next * 3));
                    next += 1;
                }
                None => std::thread::yield_now(),
            }
        }
        producer.join().unwrap();
        assert!(rx.is_empty());
    }
}
