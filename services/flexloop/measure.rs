//! `flexloop measure`: a loop's frequency responses (docs/control.md,
//! "Measuring the loop").
//!
//! - `measure RUN_DIR [--fit MODES]`: every measurement of a finished (or
//!   running) run, from its run directory alone: the scenario's `[measure]`
//!   and each one ordered while it ran (its `measure` events).
//! - `measure --running [--prefix P] FIELD=VALUE... [--fit MODES]`: orders
//!   one on the running loop (the `[measure]` fields, its start the
//!   supervisor's), waits until it is recorded, and computes it.
//!
//! Each is printed against the design and written under
//! `RUN_DIR/measurement/` as `frf.csv` and `frf.npz`; with `--fit` a modal
//! model fitted to the measured plant is written as a `state-space` plant
//! file (`plant-fit.npz`).

use anyhow::{Context, bail};
use flexloop_analysis::loop_measurement::{LoopMeasurement, MIN_COHERENCE, MeasurementError};
use flexloop_analysis::run_log::JoinedLog;
use flexloop_components::ExcitationPlan;
use flexloop_control::modal_fit::{ModalFit, ModalFitSpec};
use flexloop_design::LoopDesign;
use flexloop_modelfile::{Array, ModelArrays};
use flexloop_runfiles::RunDir;
use flexloop_runfiles::events::{EventKind, parse_events};
use flexloop_scenario::schema::MeasureSection;
use flexloop_scenario::{Mode, Overrides, Scenario};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// `measure RUN_DIR | --running FIELD=VALUE... [--fit MODES]`.
#[derive(Debug, clap::Args)]
pub struct MeasureArgs {
    /// The run's directory; with --running, the `[measure]` fields as
    /// FIELD=VALUE (point="plant-input" f_min_hz=5 f_max_hz=2000 amplitude=200)
    #[arg(required = true, value_name = "RUN_DIR | FIELD=VALUE")]
    pub args: Vec<String>,
    /// Order the measurement on the running loop (--prefix names it)
    #[arg(long)]
    pub running: bool,
    #[command(flatten)]
    pub which: crate::loop_command::PrefixArg,
    /// Fit a modal model (a rigid body and this many flexible modes) to
    /// the measured plant and write it as plant-fit.npz
    #[arg(long, value_name = "MODES")]
    pub fit: Option<usize>,
    /// No rigid body in the fitted model (a plant held to the ground)
    #[arg(long, requires = "fit")]
    pub no_rigid_body: bool,
}

pub fn measure(args: MeasureArgs) -> anyhow::Result<i32> {
    if args.running {
        return measure_running(&args);
    }
    if args.which.prefix.is_some() {
        bail!("--prefix names a running loop: add --running, or give a run directory alone");
    }
    let [run_dir] = args.args.as_slice() else {
        bail!("give one run directory (or --running and the [measure] fields)");
    };
    let run = Run::open(Path::new(run_dir))?;
    let joined = JoinedLog::open(run.dir.path())?;
    let measurements = run.measurements()?;
    if measurements.is_empty() {
        bail!(
            "{run_dir}: the run measured nothing: add a [measure] to the scenario \
             (scenarios/README.md), or order one with `flexloop measure --running`"
        );
    }
    for (label, plan) in measurements {
        run.compute(&label, plan, &joined, &args)?;
    }
    Ok(0)
}

/// Orders the measurement, waits for its samples, computes it.
fn measure_running(args: &MeasureArgs) -> anyhow::Result<i32> {
    let mut fields = Vec::new();
    for text in &args.args {
        let Some((field, value)) = text.split_once('=') else {
            bail!("{text:?}: give each [measure] field as FIELD=VALUE");
        };
        fields.push((field.trim().to_string(), value.trim().to_string()));
    }
    let (run_dir, ordered) =
        flexloop_supervisor::attach::measure(args.which.prefix.as_deref(), &fields)
            .map_err(|e| anyhow::anyhow!("measurement refused: {e}"))?;
    let run = Run::open(&run_dir)?;
    let rate = run.scenario.timing.rate_hz;
    println!(
        "measuring: samples {} to {} ({:.2} s of loop time), recorded in {}",
        ordered.start_seq,
        ordered.end_seq,
        (ordered.end_seq - ordered.start_seq) as f64 / rate,
        run_dir.display()
    );
    let plan = run.plan_of(&ordered.table)?;
    let label = format!("at-{}", ordered.start_seq);
    // Until its last period is in the sample file (the logger writes it in
    // chunks), bounded: the loop's time at its rate, and a minute more for a
    // slow lockstep loop or a late logger.
    let patience = Duration::from_secs_f64((ordered.end_seq - ordered.start_seq) as f64 / rate)
        + Duration::from_secs(60);
    let since = Instant::now();
    loop {
        std::thread::sleep(Duration::from_millis(500));
        // The run ended (its summary is written last): the log read after
        // this holds all it ever will.
        let ended = run.dir.summary().exists();
        let joined = JoinedLog::open(&run_dir)?;
        match run.compute(&label, plan.clone(), &joined, args) {
            Ok(()) => return Ok(0),
            Err(e) => {
                let recording = matches!(
                    e.downcast_ref::<MeasurementError>(),
                    Some(MeasurementError::Unfinished { .. } | MeasurementError::Missing { .. })
                );
                if !recording || ended || since.elapsed() > patience {
                    return Err(e);
                }
            }
        }
    }
}

/// A run directory and the scenario its measurements are judged against.
struct Run {
    dir: RunDir,
    scenario: Scenario,
}

impl Run {
    fn open(path: &Path) -> anyhow::Result<Self> {
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
        Ok(Self { dir, scenario })
    }

    /// The scenario's `[measure]`, and each one ordered while it ran.
    fn measurements(&self) -> anyhow::Result<Vec<(String, ExcitationPlan)>> {
        let mut found = Vec::new();
        if let Some(plan) = self.scenario.measurement_plan()? {
            found.push(("scenario".to_string(), plan));
        }
        let events = std::fs::read_to_string(self.dir.events()).unwrap_or_default();
        let events =
            parse_events(&events).with_context(|| format!("{}", self.dir.events().display()))?;
        for event in events {
            if let EventKind::Measure(ordered) = event.kind {
                let plan = self.plan_of(&ordered.outcome.table)?;
                found.push((format!("at-{}", ordered.outcome.start_seq), plan));
            }
        }
        Ok(found)
    }

    /// The plan of a measurement ordered with `table` (its `[measure]`).
    fn plan_of(&self, table: &str) -> anyhow::Result<ExcitationPlan> {
        let section = MeasureSection::from_table(table).context("the ordered [measure]")?;
        let mut scenario = self.scenario.clone();
        // Checked when it was ordered; the run's end may have come since.
        scenario.timing.duration_s = 0.0;
        scenario.measure = Some(section);
        scenario
            .measurement_plan()?
            .context("the ordered measurement has no plan")
    }

    /// One measurement, printed and written under `measurement/[label]`.
    fn compute(
        &self,
        label: &str,
        plan: ExcitationPlan,
        joined: &JoinedLog,
        args: &MeasureArgs,
    ) -> anyhow::Result<()> {
        let design = LoopDesign::from_scenario(&self.scenario)?;
        let measurement = LoopMeasurement::of_log(&design, &plan, &joined.log)?;
        println!("measurement {label}:");
        print!("{}", measurement.render_text());
        let out = if label == "scenario" {
            self.dir.measurement()
        } else {
            self.dir.measurement().join(label)
        };
        std::fs::create_dir_all(&out)
            .with_context(|| format!("cannot create {}", out.display()))?;
        let (csv, npz) = (out.join("frf.csv"), out.join("frf.npz"));
        measurement
            .write_csv(&csv)
            .with_context(|| format!("cannot write {}", csv.display()))?;
        measurement.write_npz(&npz)?;
        println!("responses: {} and {}", csv.display(), npz.display());
        if let Some(modes) = args.fit {
            fit(
                &measurement,
                modes,
                !args.no_rigid_body,
                self.scenario.timing.rate_hz,
                &out,
            )?;
        }
        Ok(())
    }
}

/// A modal model fitted to the measured plant, written as a plant file.
fn fit(
    measurement: &LoopMeasurement,
    modes: usize,
    rigid_body: bool,
    rate_hz: f64,
    out: &Path,
) -> anyhow::Result<PathBuf> {
    let plant = measurement
        .response("P")
        .expect("every measurement has the plant");
    let spec = ModalFitSpec {
        min_coherence: MIN_COHERENCE,
        ..ModalFitSpec::new(modes, rigid_body)
    };
    let fit = ModalFit::from_frf(&plant.measured, rate_hz, &spec).context("the modal fit")?;
    let model = fit.state_space();
    let file = out.join("plant-fit.npz");
    ModelArrays::write_npz(
        &file,
        &[
            ("A", Array::from_matrix(&model.a)),
            ("B", Array::from_matrix(&model.b)),
            ("C", Array::from_matrix(&model.c)),
            ("D", Array::from_matrix(&model.d)),
        ],
    )?;
    if let Some(gain) = fit.rigid_gain {
        println!("fitted rigid body: 1/({:.4} s^2)", 1.0 / gain);
    }
    for mode in &fit.modes {
        println!(
            "fitted mode: {:.2} Hz, damping {:.4}, modal gain {:.4e}",
            mode.frequency_hz, mode.damping, mode.gain
        );
    }
    let q = &fit.quality;
    println!(
        "fit on {} lines: {:.2} dB rms, at most {:.2} dB and {:.1} deg from the measurement",
        q.lines_used, q.rms_error_db, q.max_error_db, q.max_error_degrees
    );
    println!(
        "plant file: {} ([plant] model = \"state-space\", file = ...; docs/own-plant.md)",
        file.display()
    );
    Ok(file)
}
