//! The measurements of a run (docs/control.md §14): the scenario's
//! `[measure]` and each one ordered on the running loop (its `measure`
//! event). `flexloop measure` and `flexloop report` both list them here, so
//! that the two show the same measurements, each judged against the loop it
//! measured: the scenario's `[measure]` against the scenario the run
//! started with, an ordered one against the scenario as it stood when it
//! was ordered (the supervisor's snapshot; swaps and sets may follow).

use anyhow::Context;
use flexloop_components::ExcitationPlan;
use flexloop_runfiles::RunDir;
use flexloop_runfiles::events::{EventKind, parse_events};
use flexloop_scenario::schema::MeasureSection;
use flexloop_scenario::{Mode, Overrides, Scenario};
use std::path::{Path, PathBuf};

/// The label of the scenario's `[measure]`; its files are `measurement/`'s own.
pub const SCENARIO_LABEL: &str = "scenario";

/// The label of a measurement ordered to start at `start_seq`, the name of
/// its folder under `measurement/` (`RunDir::ordered_measurement`).
pub fn ordered_label(start_seq: u64) -> String {
    RunDir::new("")
        .ordered_measurement(start_seq)
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// A run directory and the scenario as it stands (after sets and swaps).
pub struct MeasuredRun {
    pub dir: RunDir,
    pub scenario: Scenario,
    /// The file `scenario` was read from.
    pub file: PathBuf,
    /// The run's own rate, mode and duration.
    overrides: Overrides,
}

/// The loop a measurement measured, and its excitation.
#[derive(Clone)]
pub struct Judged {
    pub scenario: Scenario,
    /// The file `scenario` was read from.
    pub file: PathBuf,
    pub plan: ExcitationPlan,
}

/// One measurement of a run.
pub struct Measurement {
    /// [`SCENARIO_LABEL`] or [`ordered_label`].
    pub label: String,
    /// The tick an ordered measurement was ordered to start at; None for
    /// the scenario's `[measure]`.
    pub ordered_start: Option<u64>,
    /// The loop it measured and its excitation, or why they cannot be read
    /// (a `measure` event whose table does not read).
    pub judged: anyhow::Result<Judged>,
}

/// Where `flexloop measure` writes the measurement `label` of the run `dir`.
pub fn folder_of(dir: &RunDir, label: &str) -> PathBuf {
    if label == SCENARIO_LABEL {
        dir.measurement()
    } else {
        dir.measurement().join(label)
    }
}

impl MeasuredRun {
    pub fn open(path: &Path) -> anyhow::Result<Self> {
        let dir = RunDir::new(path);
        // The run's own rate, mode and duration, whatever the file says now;
        // the scenario as it stands (after sets and swaps) if it changed.
        let summary = dir.read_summary().ok();
        let overrides = Overrides {
            rate_hz: summary.as_ref().map(|s| s.rate_hz),
            mode: summary.as_ref().and_then(|s| Mode::parse(&s.mode)),
            duration_s: summary.as_ref().map(|s| s.duration_s),
            no_realtime: false,
            tick: None,
        };
        let file = [dir.scenario_now(), dir.scenario_copy()]
            .into_iter()
            .find(|p| p.exists())
            .unwrap_or_else(|| dir.scenario_copy());
        let scenario = Scenario::load(&file, &overrides)?;
        Ok(Self {
            dir,
            scenario,
            file,
            overrides,
        })
    }

    /// The scenario's `[measure]`, and each one ordered while it ran, in
    /// the order they were ordered.
    pub fn measurements(&self) -> anyhow::Result<Vec<Measurement>> {
        let mut found = Vec::new();
        // The scenario's own ran from the start: the loop as it started
        // (a swap keeps `[measure]`, so the scenario now has the same one).
        if self.scenario.measure.is_some() {
            let file = self.dir.scenario_copy();
            let judged = Scenario::load(&file, &self.overrides)
                .map_err(anyhow::Error::from)
                .and_then(|scenario| {
                    let plan = scenario
                        .measurement_plan()?
                        .context("the scenario's [measure] has no plan")?;
                    Ok(Judged {
                        scenario,
                        file,
                        plan,
                    })
                });
            found.push(Measurement {
                label: SCENARIO_LABEL.to_string(),
                ordered_start: None,
                judged,
            });
        }
        let path = self.dir.events();
        let events = std::fs::read_to_string(&path).unwrap_or_default();
        let events = parse_events(&events).with_context(|| format!("{}", path.display()))?;
        for event in events {
            if let EventKind::Measure(ordered) = event.kind {
                let start = ordered.outcome.start_seq;
                found.push(Measurement {
                    label: ordered_label(start),
                    ordered_start: Some(start),
                    judged: self
                        .ordered(start, &ordered.outcome.table)
                        .with_context(|| {
                            format!(
                                "{}: the measurement ordered at tick {start}",
                                path.display()
                            )
                        }),
                });
            }
        }
        Ok(found)
    }

    /// The measurement ordered at `start` with `table` (its `[measure]`):
    /// the loop as it stood then (the supervisor's snapshot; a run recorded
    /// before snapshots were taken: the scenario as it stands) and its plan.
    pub fn ordered(&self, start: u64, table: &str) -> anyhow::Result<Judged> {
        let snapshot = self.dir.measured_scenario(start);
        let (scenario, file) = if snapshot.exists() {
            (Scenario::load(&snapshot, &self.overrides)?, snapshot)
        } else {
            (self.scenario.clone(), self.file.clone())
        };
        let section = MeasureSection::from_table(table).context("the ordered [measure]")?;
        let mut planned = scenario.clone();
        // Checked when it was ordered; the run's end may have come since.
        planned.timing.duration_s = 0.0;
        planned.measure = Some(section);
        let plan = planned
            .measurement_plan()?
            .context("the ordered measurement has no plan")?;
        Ok(Judged {
            scenario,
            file,
            plan,
        })
    }
}
