//! `flexloop bench --sweep`: how the loop's cost grows with the sample rate,
//! the observer's size and the number of axes. Every point is a real run of
//! the four processes (realtime, logger on, as `bench`); the machine's floors
//! are measured once, in the same invocation, at 10 kHz.
//!
//! The rate series runs `thesis-mc` (the thesis' reduced Kalman observer with
//! MC, 37 Hz PID): it designs at every rate of the grid, while the default
//! scenario's AD puts a band-pass on modes at 942 and 1396 Hz, above the
//! Nyquist frequency of 1 and 2 kHz. The size and axes series start from the
//! default scenario at 10 kHz.
//!
//! - [`cpu`]: each process's CPU time over a point's run.
//! - [`results`]: the tables, findings and figures.

mod cpu;
mod results;

use crate::probes;
use anyhow::{Context, bail};
use cpu::CpuWindow;
use flexloop_design::LoopDesign;
use flexloop_node::overrides::OverrideFlags;
use flexloop_runfiles::RunDir;
use flexloop_runfiles::bench::{Floors, SweepFile, SweepMeasurement, SweepPoint, SweepResult};
use flexloop_runtime::latency::Metric;
use flexloop_runtime::shutdown;
use flexloop_scenario::{Mode, Overrides, Scenario};
use flexloop_supervisor::launch::{LoopArgs, named_scenario, prepare, resolve_scenario, supervise};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The sweep's grid (docs/benchmarks.md): rates in Hz, observer sizes in states, and the models
/// with one, two and three axes.
const RATES_HZ: [f64; 6] = [1e3, 2e3, 5e3, 10e3, 20e3, 40e3];
const STATES: [usize; 4] = [16, 32, 64, 128];
const AXES: [(&str, &str); 2] = [("mimo-example", "2×2"), ("oat-like", "3-DOF OAT-like")];
/// The rate of the size and axes series and of the floors.
const BASE_RATE_HZ: f64 = 10e3;
/// Loop misses per tick the sweep accepts (docs/benchmarks.md).
const MISS_GOAL: f64 = 1e-4;
/// CPU is measured from this share of the run on, past start-up.
const WARM_UP: f64 = 0.25;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Series {
    Rate,
    /// The default scenario at 10 kHz: the first point of the size and axes
    /// series (the thesis' SISO observer).
    #[value(skip)]
    Base,
    States,
    Axes,
}

impl Series {
    fn name(self) -> &'static str {
        match self {
            Series::Rate => "rate",
            Series::Base => "base",
            Series::States => "states",
            Series::Axes => "axes",
        }
    }
}

/// The sweep's own flags (with `bench --sweep`).
#[derive(Debug, Clone, clap::Args)]
pub struct GridArgs {
    /// With --sweep: the series to run
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        value_name = "rate,states,axes",
        requires = "sweep"
    )]
    series: Option<Vec<Series>>,
    /// With --sweep: the rate series' rates [default: 1000,2000,5000,10000,20000,40000]
    #[arg(long, value_delimiter = ',', value_name = "HZ,...", requires = "sweep")]
    rates: Option<Vec<f64>>,
    /// With --sweep: the observer sizes of the states series [default: 16,32,64,128]
    #[arg(long, value_delimiter = ',', value_name = "N,...", requires = "sweep")]
    states: Option<Vec<usize>>,
    /// With --sweep: keep every point's sample file
    #[arg(long, requires = "sweep")]
    keep_logs: bool,
}

#[derive(Debug, Clone)]
pub struct Options {
    series: Vec<Series>,
    rates_hz: Vec<f64>,
    states: Vec<usize>,
    duration_s: f64,
    probes: bool,
    no_realtime: bool,
    tick: Option<flexloop_scenario::TickWait>,
    keep_logs: bool,
    out: Option<PathBuf>,
}

impl Options {
    /// The sweep's options from `bench --sweep`'s flags, checked.
    pub fn from_args(
        grid: &GridArgs,
        overrides: &OverrideFlags,
        no_probes: bool,
        run_dir: Option<PathBuf>,
    ) -> anyhow::Result<Self> {
        let o = Options {
            series: grid
                .series
                .clone()
                .unwrap_or_else(|| vec![Series::Rate, Series::States, Series::Axes]),
            rates_hz: grid.rates.clone().unwrap_or_else(|| RATES_HZ.to_vec()),
            states: grid.states.clone().unwrap_or_else(|| STATES.to_vec()),
            duration_s: overrides.duration_s.unwrap_or(4.0),
            probes: !no_probes,
            no_realtime: overrides.no_realtime,
            tick: overrides.tick,
            keep_logs: grid.keep_logs,
            out: run_dir,
        };
        if !(o.duration_s.is_finite() && o.duration_s > 0.0) {
            bail!(
                "--duration needs a positive number of seconds per point, got {}",
                o.duration_s
            );
        }
        if let Some(r) = o
            .rates_hz
            .iter()
            .find(|r| !(r.is_finite() && **r > 0.0 && **r <= 100e3))
        {
            bail!("--rates: {r} Hz is not in (0, 100 kHz]");
        }
        let nodes = flexloop_control::models::UNIFORM_CHAIN_NODES;
        if let Some(n) = o
            .states
            .iter()
            .find(|n| !(n.is_multiple_of(2) && nodes.contains(&(*n / 2))))
        {
            bail!(
                "--states: {n} is not an even number of states from {} to {} (the uniform chain has 2 per mass)",
                2 * nodes.start(),
                2 * nodes.end()
            );
        }
        Ok(o)
    }
}

/// One run of the sweep.
#[derive(Debug, Clone)]
struct Point {
    series: Series,
    /// Directory name and table label.
    label: String,
    /// What the point varies, in words ("10 kHz", "64 states", "2×2").
    what: String,
    scenario: PathBuf,
    rate_hz: f64,
}

/// What a point measured: [`SweepMeasurement`], as `sweep.json` keeps it.
type Measured = SweepMeasurement;

fn miss_ratio(m: &Measured) -> f64 {
    m.misses as f64 / m.ticks.max(1) as f64
}

/// The plant woke within half a period of its tick on the median tick:
/// below that it cannot hold the rate at all (every tick "stalled").
fn keeps_the_grid(m: &Measured, rate_hz: f64) -> bool {
    (m.tick_lateness.p50 as f64) < 0.5e9 / rate_hz
}

pub fn sweep(o: Options) -> anyhow::Result<i32> {
    let root = o
        .out
        .clone()
        .unwrap_or_else(|| flexloop_supervisor::launch::stamped_run_dir("sweep"));
    std::fs::create_dir_all(&root).with_context(|| root.display().to_string())?;
    let base = Scenario::load(&default_scenario()?, &base_overrides(&o, BASE_RATE_HZ))?;
    let profile = crate::deployment::profile_line(&base);
    println!("{profile}");
    let points = plan(&o, &root)?;
    eprintln!(
        "flexloop bench --sweep: {} runs of {} s each, results in {}",
        points.len(),
        o.duration_s,
        root.display()
    );
    let mut results: Vec<(Point, Result<Measured, String>)> = Vec::new();
    for point in points {
        if shutdown::requested() {
            bail!("interrupted");
        }
        eprintln!("flexloop bench --sweep: {} ({})", point.label, point.what);
        let outcome = run_point(&point, &o, &root).map_err(|e| format!("{e:#}"));
        if let Err(e) = &outcome {
            eprintln!("flexloop bench --sweep: {}: {e}", point.label);
        }
        results.push((point, outcome));
    }
    let floors = if o.probes {
        let samples = (BASE_RATE_HZ * 2.0) as u64;
        Some(
            probes::Floors::measure(&base, &format!("flxsweep{}_", std::process::id()), samples)?
                .file(),
        )
    } else {
        None
    };
    let text = results::tables(&results, floors.as_ref());
    print!("{text}");
    write_results(
        &root,
        &o,
        &results,
        floors.as_ref(),
        &format!("\n{profile} (every point's scenario places its processes the same way).\n{text}"),
    )?;
    Ok(0)
}

fn default_scenario() -> anyhow::Result<PathBuf> {
    resolve_scenario(None)
}

fn base_overrides(o: &Options, rate_hz: f64) -> Overrides {
    Overrides {
        rate_hz: Some(rate_hz),
        duration_s: Some(o.duration_s),
        mode: Some(Mode::Realtime),
        no_realtime: o.no_realtime,
        tick: o.tick,
    }
}

/// The runs, in order.
fn plan(o: &Options, root: &Path) -> anyhow::Result<Vec<Point>> {
    let mut points = Vec::new();
    if o.series.contains(&Series::Rate) {
        let rate_scenario = named_scenario("thesis-mc")?;
        for &rate in &o.rates_hz {
            points.push(Point {
                series: Series::Rate,
                label: format!("rate-{}hz", rate.round()),
                what: format!("thesis-mc at {} kHz", rate / 1e3),
                scenario: rate_scenario.clone(),
                rate_hz: rate,
            });
        }
    }
    if o.series.contains(&Series::States) || o.series.contains(&Series::Axes) {
        points.push(Point {
            series: Series::Base,
            label: "default".into(),
            what: "default (thesis MC+AD), 10 kHz".into(),
            scenario: default_scenario()?,
            rate_hz: BASE_RATE_HZ,
        });
    }
    if o.series.contains(&Series::States) {
        let chain = named_scenario("uniform-chain")?;
        let text = std::fs::read_to_string(&chain).with_context(|| chain.display().to_string())?;
        for &states in &o.states {
            let nodes = states / 2;
            let file = root.join(format!("uniform-chain-{nodes}.toml"));
            std::fs::write(&file, with_nodes(&text, nodes))
                .with_context(|| file.display().to_string())?;
            points.push(Point {
                series: Series::States,
                label: format!("states-{states}"),
                what: format!("uniform chain, {nodes} masses"),
                scenario: file,
                rate_hz: BASE_RATE_HZ,
            });
        }
    }
    if o.series.contains(&Series::Axes) {
        for (name, what) in AXES {
            points.push(Point {
                series: Series::Axes,
                label: format!("axes-{name}"),
                what: what.to_string(),
                scenario: named_scenario(name)?,
                rate_hz: BASE_RATE_HZ,
            });
        }
    }
    Ok(points)
}

/// The uniform chain's scenario text with `nodes` masses.
fn with_nodes(text: &str, nodes: usize) -> String {
    let mut out = String::with_capacity(text.len() + 16);
    let mut in_plant = false;
    for line in text.lines() {
        let trimmed = line.trim_start();
        if trimmed.starts_with('[') {
            in_plant = trimmed.trim_end() == "[plant]";
        }
        let key = trimmed.split('=').next().unwrap_or("").trim();
        if in_plant && key == "nodes" {
            let _ = writeln!(out, "nodes = {nodes}");
        } else if in_plant && key == "description" {
            continue;
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

fn run_point(point: &Point, o: &Options, root: &Path) -> anyhow::Result<Measured> {
    let run_dir = RunDir::new(root.join(&point.label));
    let args = LoopArgs {
        scenario: point.scenario.clone(),
        overrides: base_overrides(o, point.rate_hz),
        run_dir: Some(run_dir.path().to_path_buf()),
    };
    let prepared = prepare(&args)?;
    let design = LoopDesign::from_scenario(&prepared.scenario)?;
    let rate_hz = prepared.scenario.timing.rate_hz;
    let mut cpu = CpuWindow::new(
        &prepared.plan.prefix,
        (o.duration_s * rate_hz * WARM_UP) as u64,
        rate_hz,
    );
    supervise(prepared, |running, _| {
        cpu.observe(running);
        None
    })?;
    let summary = run_dir.read_summary()?;
    let percentiles = |metric: Metric| summary.latency(metric.name()).percentiles;
    if !o.keep_logs {
        // 15–60 MB per point; the summary and the latency log stay.
        let _ = std::fs::remove_file(run_dir.samples(0));
    }
    // Ticks and misses as the plant counted them (the logger's count misses
    // what it could not keep up with on a busy machine).
    let own = run_dir.read_plant_latency()?;
    let (cpu_per_sample_ns, cpu_share) = cpu.result();
    Ok(Measured {
        states: design.observer.estimate_map.nrows(),
        outputs: design.n_outputs,
        inputs: design.n_inputs,
        ticks: own.ticks,
        misses: own.counters.misses,
        stall_misses: own.counters.stall_misses,
        stalled_ticks: own.counters.stalled_ticks,
        round_trip: percentiles(Metric::RoundTrip),
        tick_lateness: percentiles(Metric::TickLateness),
        tick_to_command: percentiles(Metric::TickToCommand),
        observer_compute: percentiles(Metric::ObserverCompute),
        controller_compute: percentiles(Metric::ControllerCompute),
        cpu_per_sample_ns,
        cpu_share,
    })
}

fn write_results(
    root: &Path,
    o: &Options,
    results: &[(Point, Result<Measured, String>)],
    floors: Option<&Floors>,
    text: &str,
) -> anyhow::Result<()> {
    let write = |name: &str, bytes: &[u8]| {
        let path = root.join(name);
        let partial = root.join(format!(".{name}.partial"));
        std::fs::write(&partial, bytes)
            .and_then(|_| std::fs::rename(&partial, &path))
            .with_context(|| path.display().to_string())
    };
    let mut markdown = format!(
        "# flexloop bench --sweep\n\n{} s per point, realtime{}{}; host {} CPUs.\n{text}\n",
        o.duration_s,
        if o.no_realtime {
            " without real-time settings"
        } else {
            ""
        },
        o.tick.map_or(String::new(), |t| format!(
            ", tick wait {} (--tick)",
            t.as_str()
        )),
        flexloop_runtime::realtime::online_cpus()
    );
    for (name, figure) in results::figures(results) {
        write(&name, figure.to_svg().as_bytes())?;
        let _ = writeln!(markdown, "![{name}]({name})\n");
    }
    write("sweep.md", markdown.as_bytes())?;
    let document = SweepFile {
        duration_s_per_point: o.duration_s,
        points: results
            .iter()
            .map(|(p, r)| SweepPoint {
                series: p.series.name().to_string(),
                label: p.label.clone(),
                what: p.what.clone(),
                rate_hz: p.rate_hz,
                scenario: p.scenario.display().to_string(),
                result: match r {
                    Ok(m) => SweepResult::Measured(Box::new(m.clone())),
                    Err(e) => SweepResult::Failed { error: e.clone() },
                },
            })
            .collect(),
        floors: floors.copied(),
    };
    flexloop_runfiles::json::write_json_atomically(&root.join("sweep.json"), &document)?;
    println!(
        "\nsweep: {} (tables and figures), {}",
        root.join("sweep.md").display(),
        root.join("sweep.json").display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_chain_copy_has_the_nodes_asked_for() {
        let text = "name = \"u\"\n[plant]\nmodel = \"uniform-chain\"\nnodes = 32\n[observer]\nnodes_x = 1\n";
        let copy = with_nodes(text, 8);
        assert!(copy.contains("\nnodes = 8\n") && !copy.contains("nodes = 32"));
        assert!(copy.contains("nodes_x = 1"));
    }

    #[test]
    fn bad_lists_name_their_flag() {
        use clap::Parser;
        let parse = |v: &[&str]| -> Result<Options, String> {
            let line = ["flexloop", "bench", "--sweep"].iter().chain(v);
            match crate::Cli::try_parse_from(line)
                .map_err(|e| e.to_string())?
                .command
            {
                crate::Command::Bench(args) => {
                    Options::from_args(&args.grid, &args.overrides, args.no_probes, args.run_dir)
                        .map_err(|e| e.to_string())
                }
                other => panic!("not bench: {other:?}"),
            }
        };
        assert!(parse(&["--states", "15"]).unwrap_err().contains("--states"));
        assert!(
            parse(&["--states", "256"])
                .unwrap_err()
                .contains("--states")
        );
        assert!(parse(&["--rates", "0"]).unwrap_err().contains("--rates"));
        assert!(
            parse(&["--rates", "2000,x"])
                .unwrap_err()
                .contains("--rates")
        );
        assert!(
            parse(&["--series", "rate,size"])
                .unwrap_err()
                .contains("size")
        );
        assert!(parse(&["--series", "base"]).unwrap_err().contains("base"));
        let o = parse(&["--series", "states", "--states", "16,128"]).unwrap();
        assert_eq!((o.series, o.states), (vec![Series::States], vec![16, 128]));
        assert_eq!(o.duration_s, 4.0);
    }
}
