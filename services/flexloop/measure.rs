//! `flexloop measure RUN_DIR [--fit MODES]`: the frequency responses of a
//! run whose scenario had a `[measure]`, from its run directory alone
//! (docs/control.md, "Measuring the loop"): printed against the design,
//! written as `measurement/frf.csv` and `frf.npz`, and with `--fit` a modal
//! model fitted to the measured plant, written as a `state-space` plant file.

use anyhow::{Context, bail};
use flexloop_analysis::loop_measurement::{LoopMeasurement, LoopSignals, MIN_COHERENCE};
use flexloop_analysis::run_log::JoinedLog;
use flexloop_control::modal_fit::{ModalFit, ModalFitSpec};
use flexloop_design::LoopDesign;
use flexloop_modelfile::{Array, ModelArrays};
use flexloop_runfiles::RunDir;
use flexloop_scenario::{Mode, Overrides, Scenario};
use std::path::PathBuf;

/// `measure RUN_DIR [--fit MODES]`.
#[derive(Debug, clap::Args)]
pub struct MeasureArgs {
    /// The run's directory (its scenario had a [measure])
    pub run_dir: PathBuf,
    /// Fit a modal model (a rigid body and this many flexible modes) to
    /// the measured plant and write it as measurement/plant-fit.npz
    #[arg(long, value_name = "MODES")]
    pub fit: Option<usize>,
    /// No rigid body in the fitted model (a plant held to the ground)
    #[arg(long, requires = "fit")]
    pub no_rigid_body: bool,
}

pub fn measure(args: MeasureArgs) -> anyhow::Result<i32> {
    let run_dir = RunDir::new(&args.run_dir);
    let summary = run_dir.read_summary()?;
    // The run's own rate, mode and duration, whatever the file says now.
    let overrides = Overrides {
        rate_hz: Some(summary.rate_hz),
        mode: Mode::parse(&summary.mode),
        duration_s: Some(summary.duration_s),
        no_realtime: false,
        tick: None,
    };
    let scenario = Scenario::load(&run_dir.scenario_copy(), &overrides)?;
    let design = LoopDesign::from_scenario(&scenario)?;
    let Some(plan) = design.measurement.clone() else {
        bail!(
            "{}: the run's scenario has no [measure]: add one (scenarios/README.md) and run it again",
            args.run_dir.display()
        );
    };
    let joined = JoinedLog::open(run_dir.path())?;
    let signals = LoopSignals::from_measurements(&plan, joined.log.measurements())
        .with_context(|| args.run_dir.display().to_string())?;
    let measurement = LoopMeasurement::compute(&design, &plan, &signals)
        .with_context(|| args.run_dir.display().to_string())?;
    print!("{}", measurement.render_text());

    let out = run_dir.measurement();
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let (csv, npz) = (out.join("frf.csv"), out.join("frf.npz"));
    measurement
        .write_csv(&csv)
        .with_context(|| format!("cannot write {}", csv.display()))?;
    measurement.write_npz(&npz)?;
    println!("responses: {} and {}", csv.display(), npz.display());

    if let Some(modes) = args.fit {
        let plant = measurement
            .response("P")
            .expect("every measurement has the plant");
        let spec = ModalFitSpec {
            min_coherence: MIN_COHERENCE,
            ..ModalFitSpec::new(modes, !args.no_rigid_body)
        };
        let fit = ModalFit::from_frf(&plant.measured, scenario.timing.rate_hz, &spec)
            .with_context(|| format!("{}: the modal fit", args.run_dir.display()))?;
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
    }
    Ok(0)
}
