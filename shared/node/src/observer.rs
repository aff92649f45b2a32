//! The observer process: wakes on y(k), publishes the estimate for tick k+1.
//! What is its own in the life every loop component shares
//! ([`crate::instance`]).

use crate::args::{Role, ServiceArgs};
use crate::duty::Duty;
use crate::handover::ActivationView;
use crate::instance::{Component, Instance, Ports};
use crate::replay::{CatchUp, Replayed};
use crate::{NodeError, await_peers};
use flexloop_components::estimation_law::{EstimationLaw, ObserverSetup, stamp_estimate};
use flexloop_design::LoopDesign;
use flexloop_protocol::channels::{
    ESTIMATE, MEASUREMENT, MEASUREMENT_REPLAY, OBSERVER_STATE, OBSERVER_WAKEUP,
};
use flexloop_protocol::{Activation, Channel, Estimate, Handover, Joining, Measurement, flags};
use flexloop_runtime::wait::wait_readable;
use flexloop_runtime::{monotonic_ns, shutdown};
use flexloop_scenario::{ProgramRole, Scenario};
use flexloop_transport::{Inlet, LoopNode, Outlet};
use std::time::{Duration, Instant};

/// An observer instance's own: its law and what it took over.
pub(crate) struct Observer<L> {
    core: Stamped<L>,
    shadow_estimate: Box<Estimate>,
    /// Whether the core holds a state handed over (not its initial one).
    copied: bool,
    /// The controller, its warm spare and the logger.
    expected_readers: usize,
    /// It joined a loop already ticking (not a replacement before tick 0).
    joined_running_loop: bool,
}

/// The observer's own ports.
pub(crate) struct Own {
    /// Only for a restart (or a spare, which may serve one). A joining
    /// instance leaves it alone: the supervisor may have begun it already,
    /// and an older one's leftovers are older than the state taken over
    /// (the catch-up skips them).
    replay: Option<Inlet<Measurement>>,
    estimates: Outlet<Estimate>,
}

impl<L: EstimationLaw> Component for Observer<L> {
    const ROLE: Role = Role::Observer;
    const STATE: &'static Channel = &OBSERVER_STATE;
    type Own = Own;

    fn open_measurements(
        node: &LoopNode,
        args: &ServiceArgs,
        scenario: &Scenario,
    ) -> Result<Inlet<Measurement>, NodeError> {
        // A restart's queue holds what arrives while it catches up (see
        // `catch_up`): 51 ms at 10 kHz.
        let depth = if may_restart(args, scenario) {
            MEASUREMENT.qos.logger_buffer_size
        } else {
            MEASUREMENT.qos.loop_buffer_size
        };
        Ok(Inlet::<Measurement>::open_woken_by(
            node,
            &MEASUREMENT,
            &OBSERVER_WAKEUP,
            depth,
        )?)
    }

    fn open_own(
        node: &LoopNode,
        args: &ServiceArgs,
        scenario: &Scenario,
        measurements: &Inlet<Measurement>,
        _activation: &mut ActivationView,
    ) -> Result<Option<Own>, NodeError> {
        let replay = if may_restart(args, scenario) {
            Some(Inlet::<Measurement>::open_polling(
                node,
                &MEASUREMENT_REPLAY,
                MEASUREMENT_REPLAY.qos.loop_buffer_size,
            )?)
        } else {
            None
        };
        if !await_peers(
            || Ok(measurements.publishers() >= 1),
            || "no measurement publisher (plant)".into(),
        )? {
            return Ok(None);
        }
        measurements.connect()?;
        // Opened only now: the controller takes the first estimate as the
        // sign that the observer is connected and ready.
        let estimates = Outlet::<Estimate>::open(node, &ESTIMATE)?;
        Ok(Some(Own { replay, estimates }))
    }

    fn design(
        design: &LoopDesign,
        scenario: &Scenario,
        args: &ServiceArgs,
    ) -> Result<Self, NodeError> {
        let setup = ObserverSetup::new(scenario, design, args.generation, ProgramRole::Observer);
        let law = L::new(&setup).map_err(|e| NodeError::Law(format!("observer: {e}")))?;
        crate::program_params::record(&setup, args)?;
        Ok(Self {
            core: Stamped {
                law,
                n_outputs: design.n_outputs,
                n_inputs: design.n_inputs,
                converging: Converging::No,
            },
            shadow_estimate: Box::default(),
            copied: false,
            joined_running_loop: false,
            expected_readers: 1
                + usize::from(scenario.supervision.warm_spares)
                + usize::from(scenario.logger.enabled),
        })
    }

    /// This measurement yields the estimate for the next tick.
    fn owner(activation: &Activation, seq: u64) -> u32 {
        activation.observer_for(seq + 1)
    }

    fn named(activation: &Activation) -> u32 {
        activation.observer_generation
    }

    /// A replacement for an observer that died before tick 0 must start the
    /// loop like the first one did: no wake-up from the plant for 200 ms
    /// means the loop has not started (a first estimate that turns out not
    /// to be needed is refused by the controller: its generation does not
    /// own sample 0). A restart also knows it by the state the supervisor
    /// hands on (a lockstep loop waits for this very observer and publishes
    /// nothing).
    fn enter(
        &mut self,
        instance: &mut Instance,
        ports: &mut Ports<Own>,
    ) -> Result<bool, NodeError> {
        let restart = instance.joining == Joining::Restart;
        // A restart waits for that state (the supervisor hands it on every
        // 1 ms) before anything else: it owns samples from the announcement on.
        let loop_running = instance.joining.is_late() && {
            let since = Instant::now();
            let mut measured = false;
            loop {
                if restart {
                    instance.take_handovers(&ports.states_in)?;
                    if instance.handovers.newest().is_some() {
                        break true;
                    }
                }
                if measured {
                    std::thread::sleep(Duration::from_millis(1));
                } else {
                    let wait_ns = if restart { 5_000_000 } else { 200_000_000 };
                    measured = matches!(
                        wait_readable(&[ports.measurements.fd()], wait_ns),
                        Ok(flexloop_runtime::wait::Readiness::Ready(_))
                    );
                }
                let waited = since.elapsed();
                if measured && (!restart || waited >= RESTART_STATE_WAIT) {
                    break true;
                }
                if (!measured && waited >= Duration::from_millis(200)) || shutdown::requested() {
                    break false;
                }
            }
        };
        self.joined_running_loop = loop_running;
        if loop_running {
            return Ok(true);
        }
        let estimates = &ports.own.estimates;
        let expected_readers = self.expected_readers;
        if !await_peers(
            || Ok(estimates.subscribers() >= expected_readers),
            || {
                format!(
                    "{} of {expected_readers} estimate readers (controller, its spare, logger)",
                    estimates.subscribers()
                )
            },
        )? {
            return Ok(false);
        }
        // The estimate for tick 0 is the initial state; history keeps it for a
        // controller that connects later.
        let generation = instance.generation();
        estimates.publish(|e| {
            self.core.initial(e);
            e.generation = generation;
            e.published_ns = monotonic_ns();
        })?;
        estimates.notify()?;
        Ok(true)
    }

    /// A restart owns the estimates its dead predecessor left unserved at
    /// once: it takes over the predecessor's last state and steps through
    /// the measurements since, without waiting for a live one (in lockstep
    /// none comes: the loop waits for the estimate this observer owes). In
    /// lockstep it publishes the estimates it owns as it goes.
    fn resume(&mut self, instance: &mut Instance, ports: &mut Ports<Own>) -> Result<(), NodeError> {
        let Some(replay) = restart_replay(instance, &ports.own) else {
            return Ok(());
        };
        let Some(h) = instance
            .handovers
            .newest()
            .copied()
            .filter(|h| self.core.load(h))
        else {
            // Nothing of its predecessor to go on from: its own initial
            // state, on a loop that has moved since tick 0.
            if self.joined_running_loop {
                self.core.start_converging();
            }
            return Ok(());
        };
        self.copied = true;
        let (generation, lockstep) = (instance.generation(), instance.lockstep);
        let (activation, estimates) = (&mut ports.activation, &ports.own.estimates);
        let mut published = false;
        instance.replaying();
        let caught = catch_up(
            &mut self.core,
            h.seq,
            None,
            replay,
            &ports.measurements,
            &ports.states_out,
            instance,
            &mut self.shadow_estimate,
            |m, e| {
                if lockstep && activation.refresh()?.observer_for(m.seq + 1) == generation {
                    let now = monotonic_ns();
                    estimates.publish(|out| {
                        *out = *e;
                        out.generation = generation;
                        out.received_ns = now;
                        out.published_ns = now;
                    })?;
                    estimates.notify()?;
                    published = true;
                }
                Ok(())
            },
        )?;
        eprintln!("flexloop-observer: {caught}");
        if caught.incomplete.is_some() {
            self.core.start_converging();
        }
        let duty = if published {
            Duty::Active
        } else {
            Duty::Shadow
        };
        instance.replayed(caught.last_seq, duty, caught.end_of_run);
        let core = &self.core;
        instance.publish_state(&ports.states_out, caught.last_seq, &[], |h| core.save(h))
    }

    fn on_wakeup(
        &mut self,
        instance: &mut Instance,
        ports: &mut Ports<Own>,
    ) -> Result<(), NodeError> {
        // Every measurement, in order: a Kalman predictor must not skip one.
        while let Some(m) = ports.measurements.receive()? {
            let received_ns = monotonic_ns();
            // As the controller: once named, at the latest at its first estimate.
            let step = instance.on_sample::<Self>(
                &mut ports.activation,
                ports.spare.as_ref(),
                m.seq,
                m.seq,
                true,
            )?;
            match step.duty {
                // Replaced: the new instance publishes from here on.
                Duty::Retiring => return Ok(()),
                Duty::Active => {
                    let (core, generation) = (&mut self.core, instance.generation());
                    ports.own.estimates.publish(|e| {
                        core.step(&m, e);
                        e.generation = generation;
                        e.received_ns = received_ns;
                        e.published_ns = monotonic_ns();
                    })?;
                    ports.own.estimates.notify()?;
                    let core = &self.core;
                    instance.publish_state(&ports.states_out, m.seq, &[], |h| core.save(h))?;
                }
                _ => {
                    let live = *m;
                    self.follow(instance, ports, &live)?;
                }
            }
            instance.served(m.flags);
        }
        Ok(())
    }

    fn report(&self, instance: &Instance) {
        let skipped = instance.skipped();
        if skipped > 0 {
            eprintln!(
                "flexloop-observer: generation {}: {skipped} measurements never arrived",
                instance.generation()
            );
        }
    }
}

impl<L: EstimationLaw> Observer<L> {
    /// Shadow: follow the active instance's state through measurement `m`,
    /// publish nothing.
    fn follow(
        &mut self,
        instance: &mut Instance,
        ports: &Ports<Own>,
        m: &Measurement,
    ) -> Result<(), NodeError> {
        instance.take_handovers(&ports.states_in)?;
        if let Some(h) = m
            .seq
            .checked_sub(1)
            .and_then(|s| instance.handovers.find(s))
        {
            self.copied |= self.core.load(h);
        } else if !self.copied
            && let Some(h) = instance.handovers.newest().copied()
            && h.seq < m.seq
            && self.core.load(&h)
        {
            self.copied = true;
            if h.seq + 1 < m.seq
                && let Some(replay) = restart_replay(instance, &ports.own)
            {
                // A restart: the dead predecessor's last state is samples
                // old; step through every one since.
                instance.replaying();
                let caught = catch_up(
                    &mut self.core,
                    h.seq,
                    Some(m),
                    replay,
                    &ports.measurements,
                    &ports.states_out,
                    instance,
                    &mut self.shadow_estimate,
                    |_, _| Ok(()),
                )?;
                eprintln!("flexloop-observer: {caught}");
                if caught.incomplete.is_some() {
                    self.core.start_converging();
                }
                instance.replayed(caught.last_seq, Duty::Shadow, caught.end_of_run);
                let core = &self.core;
                return instance
                    .publish_state(&ports.states_out, caught.last_seq, &[], |h| core.save(h));
            }
        }
        self.core.step(m, &mut self.shadow_estimate);
        // Following only once a handed-over state is there: the active
        // instance's (a swap) or, after a crash, the one the supervisor
        // keeps handing on until it sees this instance follow (published
        // before this instance subscribed, it would reach it only with the
        // next one).
        if instance.handovers.newest().is_some() {
            let core = &self.core;
            instance.publish_state(&ports.states_out, m.seq, &[], |h| core.save(h))?;
        }
        Ok(())
    }
}

/// Any instance may end up a spare that serves a restart.
fn may_restart(args: &ServiceArgs, scenario: &Scenario) -> bool {
    args.joining == Joining::Restart || scenario.supervision.warm_spares
}

/// The supervisor's replay, which only a restart catches up from.
fn restart_replay<'p>(instance: &Instance, own: &'p Own) -> Option<&'p Inlet<Measurement>> {
    own.replay
        .as_ref()
        .filter(|_| instance.joining == Joining::Restart)
}

/// How long a restart waits for its dead predecessor's state while the
/// loop runs (the supervisor hands it on every 1 ms; without it the
/// replacement goes on from its own initial state).
const RESTART_STATE_WAIT: Duration = Duration::from_secs(1);

/// How long a restarted observer waits for the next replayed measurement
/// before it goes on from where it got. Since the last one, not since the
/// start: on a loaded machine a replay that keeps coming may take longer
/// than the loop's samples the observer can hold (which it then replays).
const CATCH_UP_TIMEOUT: Duration = Duration::from_secs(1);

/// What a catch-up did, for the observer's stderr file.
struct CaughtUp {
    state_seq: u64,
    replayed: u64,
    /// The last measurement stepped (the newest live one held).
    last_seq: u64,
    /// Why the sequence has a hole, if it has one.
    incomplete: Option<String>,
    end_of_run: bool,
}

impl std::fmt::Display for CaughtUp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.incomplete {
            None => write!(
                f,
                "took over the state after sample {} and replayed {} measurements up to the live sample {}",
                self.state_seq, self.replayed, self.last_seq
            ),
            Some(why) => write!(
                f,
                "took over the state after sample {}, replayed {} measurements, then {why}: going on from sample {} with a hole in between",
                self.state_seq, self.replayed, self.last_seq
            ),
        }
    }
}

/// A restarted observer holds the state its dead predecessor last published
/// (after measurement `state_seq`) and has just received `first_live`: it
/// steps through the supervisor's replay of the measurements in between,
/// reporting first that it is catching up (which begins the replay), then
/// its progress (which paces it), while the live queue fills, and then
/// through the live samples held meanwhile. Design-time work in shadow, off
/// the loop's CPU; bounded by [`CATCH_UP_TIMEOUT`].
#[allow(clippy::too_many_arguments)]
fn catch_up(
    core: &mut Stamped<impl EstimationLaw>,
    state_seq: u64,
    first_live: Option<&Measurement>,
    replay: &Inlet<Measurement>,
    live: &Inlet<Measurement>,
    states_out: &Outlet<Handover>,
    instance: &Instance,
    scratch: &mut Estimate,
    mut stepped: impl FnMut(&Measurement, &Estimate) -> Result<(), NodeError>,
) -> Result<CaughtUp, NodeError> {
    let mut merge = CatchUp::after(state_seq);
    if let Some(m) = first_live {
        merge.hold_live(m);
    }
    // Says it is catching up from `state_seq`, its replay reader open: the
    // supervisor begins the replay on this report (the channel keeps no
    // history, and other observers read it too) and paces it by the next.
    {
        let core = &*core;
        instance.publish_state(states_out, state_seq, &[], |h| core.save(h))?;
    }
    let mut last_progress = Instant::now();
    let (mut replayed, mut reported) = (0u64, state_seq);
    let mut incomplete = None;
    'replay: loop {
        while let Some(r) = replay.receive()? {
            match merge.replayed(&r) {
                Replayed::Step => {
                    last_progress = Instant::now();
                    core.step(&r, scratch);
                    stepped(&r, scratch)?;
                    replayed += 1;
                }
                Replayed::Skip => {}
                Replayed::Gap { missing_from, got } => {
                    // The supervisor's ring lost these when it was descheduled
                    // longer than its queue lasts; this observer's live queue,
                    // subscribed before the replay began, may hold them.
                    while let Some(m) = live.receive()? {
                        merge.hold_live(&m);
                    }
                    if merge.reached_live() {
                        break 'replay;
                    }
                    incomplete = Some(format!(
                        "the replay had lost samples {missing_from} to {}",
                        got - 1
                    ));
                    break 'replay;
                }
            }
        }
        if merge.next_seq() - 1 > reported {
            reported = merge.next_seq() - 1;
            let core = &*core;
            instance.publish_state(states_out, reported, &[], |h| core.save(h))?;
        }
        while let Some(m) = live.receive()? {
            merge.hold_live(&m);
        }
        if merge.reached_live() {
            break;
        }
        if last_progress.elapsed() > CATCH_UP_TIMEOUT || shutdown::requested() {
            incomplete = Some(format!(
                "no replayed measurement after sample {} for {CATCH_UP_TIMEOUT:?}",
                merge.next_seq() - 1
            ));
            break;
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    // Drops held samples the replay already covered.
    merge.reached_live();
    let (mut last_seq, mut end_of_run) = (merge.next_seq() - 1, false);
    while let Some(m) = merge.take_held() {
        core.step(&m, scratch);
        stepped(&m, scratch)?;
        last_seq = m.seq;
        end_of_run |= m.flags & flags::END_OF_RUN != 0;
    }
    Ok(CaughtUp {
        state_seq,
        replayed,
        last_seq,
        incomplete,
        end_of_run,
    })
}

/// A law and the counts its estimates are stamped with: every estimate
/// this process publishes carries the tick it is for and the measurement it
/// came from, whatever the law wrote.
struct Stamped<L> {
    law: L,
    n_outputs: usize,
    n_inputs: usize,
    /// After a restart without a continuous state: its estimates are
    /// flagged converging for the law's settling samples.
    converging: Converging,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Converging {
    No,
    /// For this many samples from the next estimate on.
    From(u64),
    /// Until (not including) the estimate for this tick.
    Until(u64),
}

impl<L: EstimationLaw> Stamped<L> {
    fn initial(&mut self, out: &mut Estimate) {
        self.law.initial(out);
        stamp_estimate(out, None, self.n_outputs, self.n_inputs);
    }

    fn step(&mut self, m: &Measurement, out: &mut Estimate) {
        self.law.step(m, out);
        stamp_estimate(out, Some(m), self.n_outputs, self.n_inputs);
        if let Converging::From(n) = self.converging {
            self.converging = Converging::Until(out.seq + n);
        }
        match self.converging {
            Converging::Until(until) if out.seq < until => out.flags |= flags::CONVERGING,
            Converging::Until(_) => self.converging = Converging::No,
            _ => {}
        }
    }

    /// Its state is not the loop's (a restart took over nothing, or its
    /// replay had a hole): the estimates from the next on converge first.
    fn start_converging(&mut self) {
        if let Some(n) = self.law.settling_samples() {
            self.converging = Converging::From(n);
            eprintln!(
                "flexloop-observer: started without a continuous state: its next {n} estimates \
                 are flagged converging (the controller leaves out their corrections)"
            );
        }
    }

    fn save(&self, out: &mut Handover) {
        self.law.save(out);
    }

    fn load(&mut self, from: &Handover) -> bool {
        self.law.load(from)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flexloop_components::law_setup::SetupError;

    /// A law that settles in 3 samples.
    struct Quick;

    impl EstimationLaw for Quick {
        fn new(_setup: &ObserverSetup<'_>) -> Result<Self, SetupError> {
            Ok(Quick)
        }
        fn initial(&mut self, _out: &mut Estimate) {}
        fn step(&mut self, _m: &Measurement, _out: &mut Estimate) {}
        fn settling_samples(&self) -> Option<u64> {
            Some(3)
        }
    }

    fn flags_of_estimates(core: &mut Stamped<Quick>, from: u64, to: u64) -> Vec<bool> {
        (from..to)
            .map(|seq| {
                let mut e = Estimate::default();
                core.step(
                    &Measurement {
                        seq,
                        ..Measurement::default()
                    },
                    &mut e,
                );
                e.flags & flags::CONVERGING != 0
            })
            .collect()
    }

    #[test]
    fn a_restart_without_a_continuous_state_flags_its_next_settling_samples_estimates() {
        let mut core = Stamped {
            law: Quick,
            n_outputs: 1,
            n_inputs: 1,
            converging: Converging::No,
        };
        assert_eq!(flags_of_estimates(&mut core, 10, 12), [false, false]);
        core.start_converging();
        // The estimates for ticks 13, 14 and 15, then no more.
        assert_eq!(
            flags_of_estimates(&mut core, 12, 17),
            [true, true, true, false, false]
        );
        assert_eq!(core.converging, Converging::No);
    }
}
