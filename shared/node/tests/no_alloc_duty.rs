//! The duty bookkeeping every controller and observer instance runs each
//! sample ([`Standing::on_sample`]) allocates nothing, through every duty:
//! following, named, taking over, active, replaced; a standby promoted; a
//! restart after its replay. (The allocator aborts the test on any
//! allocation inside `assert_no_alloc`; components' `no_alloc_step` shows
//! the guard is armed in every profile.)

use assert_no_alloc::{AllocDisabler, assert_no_alloc};
use flexloop_node::duty::{Duty, SampleOwnership, Standing};
use flexloop_protocol::Joining;

#[global_allocator]
static ALLOCATOR: AllocDisabler = AllocDisabler;

const SAMPLES: u64 = 10_000;

/// Generation 1 owns the samples from `boundary` on, named from `named_at`
/// on; every fourth wake-up of a shadow brings a backlog.
fn ownership(seq: u64, boundary: u64, named_at: u64) -> SampleOwnership {
    let backlog = seq.is_multiple_of(4);
    SampleOwnership {
        seq,
        oldest_seq: if backlog { seq.saturating_sub(2) } else { seq },
        owner: u32::from(seq >= boundary),
        named: u32::from(seq >= named_at),
        caught_up: !backlog,
    }
}

#[test]
fn every_duty_steps_without_allocating() {
    let mut old = Standing::new(0, Joining::AtStart);
    let mut replacement = Standing::new(1, Joining::Replacement);
    let mut standby = Standing::new(1, Joining::Standby);
    let mut restart = Standing::new(1, Joining::Restart);
    let mut seen = [[false; 6]; 4];
    assert_no_alloc(|| {
        restart.replaying();
        restart.replayed(SAMPLES / 4, Duty::Shadow);
        for seq in 0..SAMPLES {
            let o = ownership(seq, SAMPLES / 2, SAMPLES / 3);
            for (instance, seen) in [&mut old, &mut replacement, &mut standby]
                .into_iter()
                .zip(&mut seen)
            {
                if instance.duty().serves() {
                    let step = instance.on_sample(&o);
                    seen[step.duty as usize] = true;
                }
            }
            if seq > SAMPLES / 4 {
                seen[3][restart.on_sample(&o).duty as usize] = true;
            }
        }
    });
    let (active, retiring, shadow, standing_by) = (
        Duty::Active as usize,
        Duty::Retiring as usize,
        Duty::Shadow as usize,
        Duty::Standby as usize,
    );
    assert!(seen[0][active] && seen[0][retiring], "the old one retired");
    assert!(
        seen[1][shadow] && seen[1][active],
        "the replacement took over"
    );
    assert!(
        seen[2][standing_by] && seen[2][active],
        "the standby was promoted"
    );
    assert!(seen[3][shadow] && seen[3][active], "the restart took over");
    assert_eq!(replacement.skipped(), 0);
}
