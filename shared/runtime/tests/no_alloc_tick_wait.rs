//! The plant's tick wait (sleep, or sleep then spin with its adaptive
//! margin) allocates nothing per tick. The global allocator aborts on any
//! allocation inside `assert_no_alloc` (the workspace turns off the crate's
//! `disable_release`; flexloop-components' no_alloc_step proves the guard
//! armed).

use assert_no_alloc::{AllocDisabler, assert_no_alloc};
use flexloop_runtime::clock::TickGrid;
use flexloop_runtime::tick_wait::{TickWait, TickWaiter};

#[global_allocator]
static ALLOCATOR: AllocDisabler = AllocDisabler;

#[test]
fn no_alloc_tick_wait() {
    for wait in [TickWait::Sleep, TickWait::SleepThenSpin] {
        // 200 µs ticks (a 5 kHz grid) leave a loaded test machine room.
        let grid = TickGrid::starting_in(200_000, 1_000_000);
        let mut waiter = TickWaiter::new(wait, grid.period_ns());
        assert_no_alloc(|| {
            for k in 0..200 {
                waiter.wait_for(grid.tick_ns(k));
            }
        });
        let c = waiter.counts();
        if wait == TickWait::SleepThenSpin {
            assert_eq!(c.spun_ticks + c.late_wakeups, 200, "{wait:?}");
        }
    }
}
