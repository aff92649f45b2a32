//! One poll's samples of a channel in sequence order: the logger and the
//! live server read the loop's channels the same way.

use crate::NodeError;
use flexloop_protocol::channels::ESTIMATE;
use flexloop_transport::Inlet;

/// Samples one poll may stage per channel: two publishers' queues.
pub const STAGED: usize = 2 * ESTIMATE.qos.logger_buffer_size;

/// One poll's samples of a channel, put in sequence order before they are
/// counted and recorded. iceoryx2 hands a subscriber one publisher's queue
/// after the other, so during a hand-over (the old and the new instance
/// both publish) a lockstep loop, which runs flat out, put hundreds of the
/// new instance's samples ahead of the old one's last: farther than the
/// gap count's reorder window, so they counted as gaps though all arrived.
/// Preallocated: sorting in place allocates nothing.
pub struct InOrder<T> {
    items: Box<[T]>,
}

impl<T: Copy + Default + std::fmt::Debug + flexloop_transport::ZeroCopySend> InOrder<T> {
    pub fn new(capacity: usize) -> Self {
        Self {
            items: vec![T::default(); capacity].into_boxed_slice(),
        }
    }

    /// Takes everything `inlet` holds, in batches of the capacity, each
    /// handed to `each` sorted by `seq`.
    pub fn drain(
        &mut self,
        inlet: &Inlet<T>,
        seq: impl Fn(&T) -> u64,
        mut each: impl FnMut(&T),
    ) -> Result<(), NodeError> {
        loop {
            let mut len = 0;
            while len < self.items.len()
                && let Some(sample) = inlet.receive()?
            {
                self.items[len] = *sample;
                len += 1;
            }
            let batch = &mut self.items[..len];
            batch.sort_unstable_by_key(&seq);
            batch.iter().for_each(&mut each);
            if len < self.items.len() {
                return Ok(());
            }
        }
    }
}
