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
//! file (`plant-fit.npz`). The round in one step (docs/control.md §14):
//! `--retune FILE` writes the run's scenario redesigned on that fit
//! (`plant.design_file`, a PID's f_bw "auto"), checked as `up` checks a
//! file; with `--running --swap` it is handed over to the running loop
//! (observer, then controller) and measured again.

use crate::run_measurements::{Judged, MeasuredRun as Run, folder_of, ordered_label};
use anyhow::{Context, bail};
use flexloop_analysis::loop_measurement::{LoopMeasurement, MIN_COHERENCE, MeasurementError};
use flexloop_analysis::run_log::JoinedLog;
use flexloop_control::modal_fit::{ModalFit, ModalFitSpec};
use flexloop_design::LoopDesign;
use flexloop_modelfile::{Array, ModelArrays};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// `measure RUN_DIR | --running FIELD=VALUE... [--fit MODES]`.
#[derive(Debug, Clone, clap::Args)]
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
    /// Write FILE: the run's scenario with its observer and controller
    /// designed on the fitted model (plant.design_file; a PID's f_bw "auto"),
    /// checked as `up` checks a file
    #[arg(long, value_name = "FILE", requires = "fit")]
    pub retune: Option<PathBuf>,
    /// With --running and --retune: hand FILE over to the running loop
    /// (observer, then controller) and measure it again
    #[arg(long, requires = "retune", requires = "running")]
    pub swap: bool,
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
        .map(|m| Ok((m.label, m.judged?)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    if measurements.is_empty() {
        bail!(
            "{run_dir}: the run measured nothing: add a [measure] to the scenario \
             (scenarios/README.md), or order one with `flexloop measure --running`"
        );
    }
    // One retuned file: from the last measurement (said when there are more).
    let last = measurements.len() - 1;
    for (i, (label, judged)) in measurements.into_iter().enumerate() {
        if i < last && args.retune.is_some() {
            println!("(--retune: from the last measurement only, not {label})");
        }
        let retune = if i == last { args.retune.clone() } else { None };
        run.compute(
            &label,
            &judged,
            &joined,
            &MeasureArgs {
                retune,
                ..args.clone()
            },
        )?;
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
    let judged = run.ordered(ordered.start_seq, &ordered.table)?;
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
        match run.compute(&label, &judged, &joined, args) {
            Ok(()) if args.swap => {
                return hand_over_and_measure_again(args, &run_dir, &judged.file);
            }
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
        judged: &Judged,
        joined: &JoinedLog,
        args: &MeasureArgs,
    ) -> anyhow::Result<()> {
        let design = LoopDesign::from_scenario(&judged.scenario)?;
        let measurement = LoopMeasurement::of_log(&design, &judged.plan, &joined.log)?;
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
            let fitted = fit(
                &measurement,
                modes,
                !args.no_rigid_body,
                self.scenario.timing.rate_hz,
                &out,
            )?;
            if let Some(file) = &args.retune {
                retune(judged, &fitted, file)?;
            }
        }
        Ok(())
    }
}

/// Writes `file`: the scenario of the loop measured, its observer and
/// controller designed on `fitted`, and checks it as `up` would.
fn retune(judged: &Judged, fitted: &Path, file: &Path) -> anyhow::Result<()> {
    let source = &judged.file;
    let scenario = &judged.scenario;
    if scenario.controller.exec.is_some() && scenario.observer.exec.is_some() {
        bail!(
            "--retune: programs of one's own serve the observer and the controller; there \
             is no built-in law to redesign on the fit"
        );
    }
    let text = std::fs::read_to_string(source).with_context(|| format!("{}", source.display()))?;
    let mut table: toml::Table =
        toml::from_str(&text).with_context(|| format!("{}", source.display()))?;
    // Its files found from wherever the new one is written.
    flexloop_scenario::plant_description::anchor_files(&mut table, source);
    let fitted = std::path::absolute(fitted)?;
    let section = |table: &mut toml::Table, name: &str| -> anyhow::Result<toml::Table> {
        match table.remove(name) {
            Some(toml::Value::Table(t)) => Ok(t),
            None => Ok(toml::Table::new()),
            Some(_) => bail!("{}: [{name}] is not a table", source.display()),
        }
    };
    // The rate and mode the loop ran at (a run's overrides are not in its
    // scenario's copy).
    let mut timing = section(&mut table, "loop")?;
    timing.insert(
        "rate_hz".into(),
        toml::Value::Float(scenario.timing.rate_hz),
    );
    timing.insert(
        "mode".into(),
        toml::Value::String(scenario.timing.mode.as_str().into()),
    );
    table.insert("loop".into(), toml::Value::Table(timing));
    let mut plant = section(&mut table, "plant")?;
    plant.insert(
        "design_file".into(),
        toml::Value::String(fitted.display().to_string()),
    );
    table.insert("plant".into(), toml::Value::Table(plant));
    let auto = scenario.controller.feedback == "pid" && scenario.controller.exec.is_none();
    if auto {
        let mut controller = section(&mut table, "controller")?;
        controller.insert("bandwidth_hz".into(), toml::Value::String("auto".into()));
        table.insert("controller".into(), toml::Value::Table(controller));
    }
    let header = format!(
        "# {} redesigned on the model fitted to its measurement ({}): its observer and \
         controller\n# designed on plant.design_file{}; the plant emulated is unchanged \
         (docs/control.md §14).\n",
        source.display(),
        fitted.display(),
        if auto {
            ", the PID's f_bw \"auto\""
        } else {
            ""
        }
    );
    let written = header + &toml::to_string(&table)?;
    let tmp = file.with_extension("toml.tmp");
    std::fs::write(&tmp, written)
        .and_then(|()| std::fs::rename(&tmp, file))
        .with_context(|| format!("cannot write {}", file.display()))?;
    let accepted = flexloop_design::acceptance::accept(
        file,
        &flexloop_scenario::Overrides::default(),
        flexloop_runtime::realtime::online_cpus(),
    )
    .with_context(|| format!("the retuned scenario {}", file.display()))?;
    println!("retuned scenario: {}", file.display());
    if let Some(p) = accepted.design.pid_bandwidth {
        println!(
            "  PID f_bw on the fit: {:.1} Hz{}",
            p.hz,
            if p.auto {
                " (\"auto\": the largest meeting the 6 dB rule on the fit)"
            } else {
                ""
            }
        );
    }
    match flexloop_analysis::loop_report::loop_report(&accepted.scenario, &accepted.design) {
        Ok(report) => println!(
            "  that design around the plant that runs: peak |S^I| {:.2} dB, |S^O| {:.2} dB: {}",
            report.peak_si_sigma_db,
            report.peak_so_sigma_db,
            if report.meets_6db_rule {
                "keeps the 6 dB rule"
            } else {
                "breaks the 6 dB rule"
            }
        ),
        Err(e) => println!("  the loop is not analysed: {e}"),
    }
    println!(
        "  hand it over: flexloop swap observer {0} && flexloop swap controller {0}",
        file.display()
    );
    Ok(())
}

/// `--swap`: the retuned scenario handed over to the running loop, the
/// observer first (the controller's corrections read its estimate), then
/// measured again with the same fields.
fn hand_over_and_measure_again(
    args: &MeasureArgs,
    run_dir: &Path,
    measured: &Path,
) -> anyhow::Result<i32> {
    let file = args
        .retune
        .as_ref()
        .expect("clap: --swap requires --retune");
    let file = std::path::absolute(file)?;
    for role in ["observer", "controller"] {
        let answer = flexloop_supervisor::conductor::request_swap(run_dir, role, &file)?;
        match (answer.ok, answer.switch) {
            (true, Some(switch)) => println!(
                "swapped the {role}: generation {} active from sample {}",
                switch.generation, switch.from_seq
            ),
            _ => {
                let refused = answer.error.as_deref().unwrap_or("no reason given");
                if role == "controller" {
                    // Both laws on one design model: the observer goes back.
                    let back = flexloop_supervisor::conductor::request_swap(
                        run_dir, "observer", measured,
                    )?;
                    if !back.ok {
                        bail!(
                            "swap of the controller refused ({refused}), and the observer's way \
                             back to {} too: {}; the observer runs the retuned design",
                            measured.display(),
                            back.error.as_deref().unwrap_or("no reason given")
                        );
                    }
                }
                bail!("swap of the {role} refused: {refused}");
            }
        }
    }
    println!("measuring the retuned loop again:");
    let again = MeasureArgs {
        args: args.args.clone(),
        running: true,
        which: crate::loop_command::PrefixArg {
            prefix: args.which.prefix.clone(),
        },
        fit: None,
        no_rigid_body: false,
        retune: None,
        swap: false,
    };
    measure_running(&again)
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
