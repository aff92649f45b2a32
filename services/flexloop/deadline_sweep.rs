//! `flexloop design --deadline-sweep [--latency RUN_DIR]`: what each command
//! deadline τ_d buys (docs/deadline.md). For τ_d from a tenth of the period
//! to the whole period (one sample of delay): the largest f_bw meeting the
//! 6 dB rule with the scenario's loop redesigned for that deadline, on the
//! scenario's outputs and, for the thesis chain's cases, on y1..y7 as the
//! thesis' rule (3.2) holds it; next to it, from a recorded realtime run,
//! the share of commands sent later than τ_d after their tick (the loop's
//! own: commands of ticks the plant woke late for are the machine's stalls
//! and left out), and the smallest τ_d whose share stays under 1e-4.

use anyhow::Context;
use flexloop_analysis::loop_report::largest_bandwidth;
use flexloop_analysis::thesis_design::{DesignCase, ThesisDesignSpec, evaluate_design_case};
use flexloop_design::LoopDesign;
use flexloop_design::plants::thesis_chain::{chain_mass, chain_modal};
use flexloop_protocol::flags;
use flexloop_recording::{LogReader, Record};
use flexloop_scenario::Scenario;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;

/// The share of late commands a deadline may cost (docs/deadline.md): one miss in
/// 10⁴ samples, a held input once a second at 10 kHz.
pub const MISS_RATE_BUDGET: f64 = 1e-4;

/// Deadlines swept, as tenths of the period.
const TENTHS: std::ops::RangeInclusive<u32> = 1..=10;

#[derive(Debug, Clone, Serialize)]
pub struct DeadlineRow {
    pub deadline_us: f64,
    /// On the scenario's outputs (what `flexloop design` searches).
    pub largest_bandwidth_hz: Option<f64>,
    /// Why there is none (the search's note, or the design's refusal).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// The thesis chain's case on every output y1..y7 (its rule (3.2)).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub largest_bandwidth_y1_y7_hz: Option<f64>,
    /// Share of the recorded commands sent later than τ_d after their tick.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub late_share: Option<f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct DeadlineSweep {
    pub period_us: f64,
    pub rows: Vec<DeadlineRow>,
    /// The recorded run the shares come from, and its command count.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub latency_run: Option<String>,
    pub commands: u64,
    /// The loop's `tick_to_command` in that run [µs]: p50, p90, p99,
    /// p99.9, p99.99 and max (the machine's stalls left out).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tick_to_command_us: Option<[f64; 6]>,
    /// Commands of ticks the plant woke late for (the machine's stalls,
    /// not the loop's latency), left out of the shares.
    pub after_stalls: u64,
    /// The smallest τ_d whose late share stays under [`MISS_RATE_BUDGET`].
    pub recommended_deadline_us: Option<f64>,
}

/// The sweep of `s` (validated), with the shares of the run in `latency`.
pub fn sweep(s: &Scenario, latency: Option<&Path>) -> anyhow::Result<DeadlineSweep> {
    let period_s = 1.0 / s.timing.rate_hz;
    let measured = match latency {
        Some(dir) => Some((dir.display().to_string(), CommandTimes::read(dir)?)),
        None => None,
    };
    let case = study_case(s);
    let mut rows = Vec::new();
    for tenth in TENTHS {
        let deadline_s = period_s * f64::from(tenth) / 10.0;
        let mut at = s.clone();
        // A whole period is the one-sample loop (a deadline must lie inside it).
        at.timing.command_deadline_us = (tenth < 10).then_some(deadline_s * 1e6);
        // The check every command makes (the deadline's own rules among
        // them), then the design.
        let designed = at.validate().and_then(|()| LoopDesign::from_scenario(&at));
        let (largest, note, y1_y7) = match designed {
            Ok(design) => {
                let (largest, note) = largest_bandwidth(&at, &design);
                let y1_y7 = match case {
                    Some(case) => thesis_rule_bandwidth(&at, case, period_s)?,
                    None => None,
                };
                (largest, note, y1_y7)
            }
            Err(e) => (None, Some(e.reason), None),
        };
        let late_share = measured
            .as_ref()
            .map(|(_, times)| times.share_later_than((deadline_s * 1e9).round() as u64));
        rows.push(DeadlineRow {
            deadline_us: deadline_s * 1e6,
            largest_bandwidth_hz: largest,
            note,
            largest_bandwidth_y1_y7_hz: y1_y7,
            late_share,
        });
    }
    let recommended_deadline_us = rows
        .iter()
        .find(|r| r.late_share.is_some_and(|share| share < MISS_RATE_BUDGET))
        .map(|r| r.deadline_us);
    Ok(DeadlineSweep {
        period_us: period_s * 1e6,
        rows,
        commands: measured.as_ref().map_or(0, |(_, t)| t.ours.len() as u64),
        tick_to_command_us: measured.as_ref().map(|(_, t)| t.percentiles_us()),
        after_stalls: measured.as_ref().map_or(0, |(_, t)| t.after_stalls),
        latency_run: measured.map(|(dir, _)| dir),
        recommended_deadline_us,
    })
}

/// When each recorded command was sent after its tick, from a run's sample
/// files: the loop's own (ticks the plant kept), and how many commands
/// answered a tick the plant itself woke late for (the machine's stalls,
/// counted apart as `flexloop bench` counts misses after stalls).
struct CommandTimes {
    ours: Vec<u64>,
    after_stalls: u64,
}

impl CommandTimes {
    fn read(dir: &Path) -> anyhow::Result<Self> {
        let run_dir = flexloop_runfiles::RunDir::new(dir);
        let files = run_dir.sample_files();
        anyhow::ensure!(
            !files.is_empty(),
            "{}: no sample file (is it a run directory?)",
            dir.display()
        );
        // Per sequence number: the tick's time and whether the plant woke
        // late for it; each command's publication.
        let mut ticks: std::collections::HashMap<u64, (u64, bool)> = Default::default();
        let mut sent: Vec<(u64, u64)> = Vec::new();
        for (_, file) in files {
            let log = LogReader::scan(&file, |r| match r {
                Record::Measurement(m) => {
                    ticks.insert(m.seq, (m.tick_ns, m.flags & flags::STALLED_TICK != 0));
                }
                // The active controller's (a standby's never act on time).
                Record::Command(c) if c.flags & flags::STANDBY == 0 => {
                    sent.push((c.seq, c.published_ns))
                }
                Record::Command(_) => {}
                Record::Estimate(_) => {}
            })
            .with_context(|| file.display().to_string())?;
            anyhow::ensure!(
                log.metadata.get("mode").is_none_or(|m| m == "realtime"),
                "{}: a lockstep run has no command times to judge a deadline by",
                file.display()
            );
        }
        let mut times = Self {
            ours: Vec::with_capacity(sent.len()),
            after_stalls: 0,
        };
        for (seq, published) in sent {
            match ticks.get(&seq) {
                Some((_, true)) => times.after_stalls += 1,
                Some((tick, false)) => times.ours.push(published.saturating_sub(*tick)),
                None => {}
            }
        }
        times.ours.sort_unstable();
        anyhow::ensure!(
            !times.ours.is_empty(),
            "{}: no command with its tick in the sample files",
            dir.display()
        );
        Ok(times)
    }

    /// p50, p90, p99, p99.9, p99.99 and max of the loop's commands [µs]
    /// (nearest rank on the sorted times).
    fn percentiles_us(&self) -> [f64; 6] {
        let at = |q: f64| {
            let rank = ((q * self.ours.len() as f64).ceil() as usize).clamp(1, self.ours.len());
            self.ours[rank - 1] as f64 / 1e3
        };
        [at(0.5), at(0.9), at(0.99), at(0.999), at(0.9999), at(1.0)]
    }

    /// The share of the loop's commands sent later than `ns` after their tick.
    fn share_later_than(&self, ns: u64) -> f64 {
        let within = self.ours.partition_point(|t| *t <= ns);
        (self.ours.len() - within) as f64 / self.ours.len() as f64
    }
}

/// The thesis study's case this scenario's loop is, if it is one (the
/// thesis chain, a PID without notches, the case's observer settings).
fn study_case(s: &Scenario) -> Option<DesignCase> {
    let o = &s.observer;
    let thesis_loop = s.plant.model == "thesis-chain"
        && s.plant.sensor_scan.is_none()
        && s.controller.feedback == "pid"
        && s.controller.notches_hz.is_empty()
        && matches!(o.flexible_modes, None | Some(3))
        && o.damping_target.is_none()
        && (!o.ad || o.damping_increase == 0.035);
    if !thesis_loop {
        return None;
    }
    let bandpass = (o.bandpass_q > 0.0).then_some(o.bandpass_q);
    let observed = o.mc || o.ad;
    if observed && o.design != "kalman" {
        return None;
    }
    let q_nu = o.q_nu.or(Some(if o.ad { 1e3 } else { 0.03 }));
    DesignCase::ALL.into_iter().find(|c| {
        // MC alone is judged with its r → e_true bound (the §10.1 row).
        *c != DesignCase::Mc
            && !c.notches()
            && c.mc() == o.mc
            && c.ad() == o.ad.then_some(bandpass)
            && (!o.mc || c.q_nu() == q_nu)
    })
}

/// The case's largest f_bw on y1..y7 for `s`'s loop timing (its deadline,
/// or its loop delay), the study at the scenario's output and chain.
fn thesis_rule_bandwidth(
    s: &Scenario,
    case: DesignCase,
    period_s: f64,
) -> anyhow::Result<Option<f64>> {
    let mut spec = match s.command_deadline_s() {
        Some(tau) => ThesisDesignSpec::on_arrival(period_s, tau),
        None => ThesisDesignSpec::discrete(period_s, 1 + s.controller.extra_delay_samples as usize),
    };
    spec.output = s.plant.output;
    spec.cases = vec![case];
    spec = spec.with_chain(chain_modal(s)?, chain_mass(s));
    Ok(evaluate_design_case(&spec, case)?.0)
}

impl DeadlineSweep {
    pub fn render_text(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "Command deadline sweep: each command u_c(k) applied on arrival at t_k + tau_d \
             (tau_d = {:.0} us is one sample of loop delay)",
            self.period_us
        );
        let y1_y7 = self
            .rows
            .iter()
            .any(|r| r.largest_bandwidth_y1_y7_hz.is_some());
        let measured = self.latency_run.is_some();
        let _ = write!(s, "  {:>9}  {:>18}", "tau_d [us]", "largest f_bw [Hz]");
        if y1_y7 {
            let _ = write!(s, "  {:>16}", "on y1..y7 [Hz]");
        }
        if measured {
            let _ = write!(s, "  {:>22}", "commands later (share)");
        }
        let _ = writeln!(s);
        for r in &self.rows {
            let hz = |v: Option<f64>| v.map_or_else(|| "-".to_string(), |v| format!("{v:.1}"));
            let _ = write!(
                s,
                "  {:>10.0}  {:>18}",
                r.deadline_us,
                hz(r.largest_bandwidth_hz)
            );
            if y1_y7 {
                let _ = write!(s, "  {:>16}", hz(r.largest_bandwidth_y1_y7_hz));
            }
            if let Some(share) = r.late_share {
                let _ = write!(s, "  {:>22}", format!("{share:.2e}"));
            }
            if let Some(note) = &r.note {
                let _ = write!(s, "  ({note})");
            }
            let _ = writeln!(s);
        }
        if let (Some(run), Some(p)) = (&self.latency_run, self.tick_to_command_us) {
            let _ = writeln!(
                s,
                "  tick_to_command in {run} (the loop's commands; the machine's stalls left out): \
                 p50 {:.1}  p90 {:.1}  p99 {:.1}  p99.9 {:.1}  p99.99 {:.1}  max {:.1} us",
                p[0], p[1], p[2], p[3], p[4], p[5]
            );
        }
        match (&self.latency_run, self.recommended_deadline_us) {
            (None, _) => {
                let _ = writeln!(
                    s,
                    "  (--latency RUN_DIR adds each tau_d's share of late commands from a \
                     recorded run of this machine, e.g. one `flexloop bench` made)"
                );
            }
            (Some(run), Some(us)) => {
                let f_bw = self
                    .rows
                    .iter()
                    .find(|r| r.deadline_us == us)
                    .and_then(|r| r.largest_bandwidth_y1_y7_hz.or(r.largest_bandwidth_hz));
                let _ = writeln!(
                    s,
                    "  recommended: tau_d = {us:.0} us, the smallest whose share of late \
                     commands in {run} ({} commands; {} after the machine's stalls left out) \
                     stays under {MISS_RATE_BUDGET:e}{}",
                    self.commands,
                    self.after_stalls,
                    f_bw.map_or_else(String::new, |hz| format!("; it allows f_bw {hz:.1} Hz"))
                );
                if (self.commands as f64) * MISS_RATE_BUDGET < 10.0 {
                    let _ = writeln!(
                        s,
                        "  (fewer than 10 misses would show the budget in {} commands: \
                         record a longer run to trust it)",
                        self.commands
                    );
                }
            }
            (Some(run), None) => {
                let _ = writeln!(
                    s,
                    "  no tau_d keeps the share of late commands in {run} under \
                     {MISS_RATE_BUDGET:e}: this machine needs the whole sample"
                );
            }
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shares_count_the_commands_later_than_the_deadline() {
        let times = CommandTimes {
            ours: vec![10_000, 20_000, 30_000, 40_000],
            after_stalls: 3,
        };
        assert_eq!(times.share_later_than(5_000), 1.0);
        assert_eq!(times.share_later_than(30_000), 0.25);
        assert_eq!(times.share_later_than(40_000), 0.0);
        assert_eq!(times.percentiles_us(), [20.0, 40.0, 40.0, 40.0, 40.0, 40.0]);
    }
}
