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

use crate::run_measurements::{MeasuredRun as Run, folder_of, ordered_label};
use anyhow::{Context, bail};
use flexloop_analysis::loop_measurement::{LoopMeasurement, MIN_COHERENCE, MeasurementError};
use flexloop_analysis::run_log::JoinedLog;
use flexloop_components::ExcitationPlan;
use flexloop_control::modal_fit::{ModalFit, ModalFitSpec};
use flexloop_design::LoopDesign;
use flexloop_modelfile::{Array, ModelArrays};
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
    // Every plan first: one that does not read stops the command before
    // anything is computed.
    let measurements = run
        .measurements()?
        .into_iter()
        .map(|m| Ok((m.label, m.plan?)))
        .collect::<anyhow::Result<Vec<_>>>()?;
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
    let label = ordered_label(ordered.start_seq);
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

impl Run {
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
        let out = folder_of(&self.dir, label);
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
