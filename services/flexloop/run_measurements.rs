//! The measurements of a run (docs/control.md §14): the scenario's
//! `[measure]` and each one ordered on the running loop (its `measure`
//! event). `flexloop measure` and `flexloop report` both list them here, so
//! that the two show the same measurements, judged against the same
//! scenario.

use anyhow::Context;
use flexloop_components::ExcitationPlan;
use flexloop_runfiles::RunDir;
use flexloop_runfiles::events::{EventKind, parse_events};
use flexloop_scenario::schema::MeasureSection;
use flexloop_scenario::{Mode, Overrides, Scenario};
use std::path::{Path, PathBuf};

/// The label of the scenario's `[measure]`; its files are `measurement/`'s own.
pub const SCENARIO_LABEL: &str = "scenario";

/// The label of a measurement ordered to start at `start_seq`, and the name
/// of its folder under `measurement/`.
pub fn ordered_label(start_seq: u64) -> String {
    format!("at-{start_seq}")
}

/// A run directory and the scenario its measurements are judged against.
pub struct MeasuredRun {
    pub dir: RunDir,
    pub scenario: Scenario,
    /// The file `scenario` was read from.
    pub file: PathBuf,
}

/// One measurement of a run.
pub struct Measurement {
    /// [`SCENARIO_LABEL`] or [`ordered_label`].
    pub label: String,
    /// The tick an ordered measurement was ordered to start at; None for
    /// the scenario's `[measure]`.
    pub ordered_start: Option<u64>,
    /// Its excitation, or why it cannot be planned (a `measure` event whose
    /// table does not read).
    pub plan: anyhow::Result<ExcitationPlan>,
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
        })
    }

    /// The scenario's `[measure]`, and each one ordered while it ran, in
    /// the order they were ordered.
    pub fn measurements(&self) -> anyhow::Result<Vec<Measurement>> {
        let mut found = Vec::new();
        if let Some(plan) = self.scenario.measurement_plan()? {
            found.push(Measurement {
                label: SCENARIO_LABEL.to_string(),
                ordered_start: None,
                plan: Ok(plan),
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
                    plan: self.plan_of(&ordered.outcome.table).with_context(|| {
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

    /// The plan of a measurement ordered with `table` (its `[measure]`).
    pub fn plan_of(&self, table: &str) -> anyhow::Result<ExcitationPlan> {
        let section = MeasureSection::from_table(table).context("the ordered [measure]")?;
        let mut scenario = self.scenario.clone();
        // Checked when it was ordered; the run's end may have come since.
        scenario.timing.duration_s = 0.0;
        scenario.measure = Some(section);
        scenario
            .measurement_plan()?
            .context("the ordered measurement has no plan")
    }
}
