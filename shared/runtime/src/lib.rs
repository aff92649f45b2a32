//! flexloop-runtime: what a real-time loop process needs besides maths and IPC.
//!
//! - [`clock`]: the absolute 100 µs tick grid (`clock_nanosleep`, TIMER_ABSTIME).
//! - [`realtime`]: SCHED_FIFO, affinity, `mlockall`, timer slack, `/dev/cpu_dma_latency`;
//!   each refusal is reported once and the process runs on.
//! - [`latency`]: bounded, allocation-free HdrHistograms and the loop's set of them,
//!   rebuilt from message timestamps against the scheduled tick (no coordinated omission).
//! - [`tick_wait`]: the plant's wait for its tick: sleep, or sleep then spin on the
//!   clock with a margin that follows its own recent wake-up lateness.
//! - [`wait`]: `ppoll` on event file descriptors with a precise timeout.
//! - [`shutdown`]: SIGINT/SIGTERM to a flag the loops poll.
//! - [`usage`]: CPU time of this process.
//! - [`spsc`]: a bounded single-producer, single-consumer queue of plain data
//!   (polling thread to worker thread: no allocation, lock or system call).

pub mod clock;
pub mod latency;
pub mod realtime;
pub mod shutdown;
pub mod spsc;
pub mod tick_wait;
pub mod usage;
pub mod wait;

pub use flexloop_protocol::time::monotonic_ns;
