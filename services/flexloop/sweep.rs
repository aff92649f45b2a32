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

use crate::supervisor::RunningLoop;
use crate::{LoopArgs, prepare, probes, run_registered_with};
use flexloop_node::Role;
use flexloop_plot::{Axis, Figure};
use flexloop_protocol::Telemetry;
use flexloop_protocol::channels::TELEMETRY;
use flexloop_runtime::latency::QUANTILE_LABELS;
use flexloop_runtime::monotonic_ns;
use flexloop_runtime::shutdown;
use flexloop_scenario::{LoopDesign, Mode, Overrides, Scenario};
use flexloop_transport::{Domain, Inlet};
use iceoryx2::prelude::{Node, ipc};
use serde_json::{Value, json};
use std::ffi::OsString;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The grid: rates in Hz, observer sizes in states, and the models
/// with one, two and three axes.
const RATES_HZ: [f64; 6] = [1e3, 2e3, 5e3, 10e3, 20e3, 40e3];
const STATES: [usize; 4] = [16, 32, 64, 128];
const AXES: [(&str, &str); 2] = [("mimo-example", "2×2"), ("oat-like", "3-DOF OAT-like")];
/// The rate of the size and axes series and of the floors.
const BASE_RATE_HZ: f64 = 10e3;
/// Loop misses per tick the issue accepts.
const MISS_GOAL: f64 = 1e-4;
/// CPU is measured from this share of the run on, past start-up.
const WARM_UP: f64 = 0.25;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Series {
    Rate,
    /// The default scenario at 10 kHz: the first point of the size and axes
    /// series (the thesis' SISO observer).
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

    fn parse(text: &str) -> Result<Self, String> {
        match text {
            "rate" => Ok(Series::Rate),
            "states" => Ok(Series::States),
            "axes" => Ok(Series::Axes),
            other => Err(format!(
                "--series: unknown series `{other}` (expected rate, states or axes)"
            )),
        }
    }
}

#[derive(Debug, Clone)]
struct Options {
    series: Vec<Series>,
    rates_hz: Vec<f64>,
    states: Vec<usize>,
    duration_s: f64,
    probes: bool,
    no_realtime: bool,
    keep_logs: bool,
    out: Option<PathBuf>,
}

const USAGE: &str =
    "flexloop bench --sweep [--series rate,states,axes] [--rates HZ,...] [--states N,...]
                     [--duration S (4, per point)] [--no-probes] [--no-realtime] [--keep-logs] [--run-dir DIR]";

fn list<T: std::str::FromStr>(text: &str, flag: &str) -> Result<Vec<T>, String> {
    text.split(',')
        .map(|v| {
            v.trim()
                .parse::<T>()
                .map_err(|_| format!("{flag}: `{v}` is not a number"))
        })
        .collect()
}

impl Options {
    fn parse(args: Vec<OsString>) -> Result<Self, String> {
        use lexopt::prelude::*;
        let mut o = Options {
            series: vec![Series::Rate, Series::States, Series::Axes],
            rates_hz: RATES_HZ.to_vec(),
            states: STATES.to_vec(),
            duration_s: 4.0,
            probes: true,
            no_realtime: false,
            keep_logs: false,
            out: None,
        };
        let mut parser = lexopt::Parser::from_args(args);
        while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
            let value = |p: &mut lexopt::Parser| -> Result<String, String> {
                Ok(p.value()
                    .map_err(|e| e.to_string())?
                    .to_string_lossy()
                    .into_owned())
            };
            match arg {
                Long("sweep") => {}
                Long("series") => {
                    o.series = value(&mut parser)?
                        .split(',')
                        .map(|s| Series::parse(s.trim()))
                        .collect::<Result<_, _>>()?
                }
                Long("rates") => o.rates_hz = list(&value(&mut parser)?, "--rates")?,
                Long("states") => o.states = list(&value(&mut parser)?, "--states")?,
                Long("duration") => {
                    o.duration_s = list::<f64>(&value(&mut parser)?, "--duration")?
                        .first()
                        .copied()
                        .unwrap_or(0.0)
                }
                Long("no-probes") => o.probes = false,
                Long("no-realtime") => o.no_realtime = true,
                Long("keep-logs") => o.keep_logs = true,
                Long("run-dir") => o.out = Some(PathBuf::from(value(&mut parser)?)),
                other => return Err(format!("{}\nusage: {USAGE}", other.unexpected())),
            }
        }
        if !(o.duration_s.is_finite() && o.duration_s > 0.0) {
            return Err(format!(
                "--duration needs a positive number of seconds per point, got {}",
                o.duration_s
            ));
        }
        if let Some(r) = o
            .rates_hz
            .iter()
            .find(|r| !(r.is_finite() && **r > 0.0 && **r <= 100e3))
        {
            return Err(format!("--rates: {r} Hz is not in (0, 100 kHz]"));
        }
        let nodes = flexloop_control::models::UNIFORM_CHAIN_NODES;
        if let Some(n) = o
            .states
            .iter()
            .find(|n| !(n.is_multiple_of(2) && nodes.contains(&(*n / 2))))
        {
            return Err(format!(
                "--states: {n} is not an even number of states from {} to {} (the uniform chain has 2 per mass)",
                2 * nodes.start(),
                2 * nodes.end()
            ));
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

/// What a point measured (from the logger's summary and the processes'
/// scheduler statistics).
#[derive(Debug, Clone, Default)]
struct Measured {
    states: usize,
    outputs: usize,
    inputs: usize,
    ticks: u64,
    misses: u64,
    stall_misses: u64,
    stalled: u64,
    /// Percentiles in ns, as [`QUANTILE_LABELS`].
    round_trip: [u64; 6],
    tick_lateness: [u64; 6],
    tick_to_command: [u64; 6],
    observer_compute: [u64; 6],
    controller_compute: [u64; 6],
    /// Per role in [`Role::ALL`] order: CPU ns per sample and share of a core,
    /// over the run past its start-up.
    cpu_per_sample_ns: [f64; 4],
    cpu_share: [f64; 4],
}

impl Measured {
    fn miss_ratio(&self) -> f64 {
        self.misses as f64 / self.ticks.max(1) as f64
    }

    /// The plant woke within half a period of its tick on the median tick:
    /// below that it cannot hold the rate at all (every tick "stalled").
    fn keeps_the_grid(&self, rate_hz: f64) -> bool {
        (self.tick_lateness[0] as f64) < 0.5e9 / rate_hz
    }

    fn json(&self) -> Value {
        let percentiles = |v: &[u64; 6]| {
            let mut m = serde_json::Map::new();
            for (label, ns) in QUANTILE_LABELS.iter().zip(v) {
                m.insert(format!("{label}_ns"), json!(ns));
            }
            Value::Object(m)
        };
        let per_role = |v: &[f64; 4]| {
            let mut m = serde_json::Map::new();
            for (role, x) in Role::ALL.iter().zip(v) {
                m.insert(role.name().into(), json!(x));
            }
            Value::Object(m)
        };
        json!({
            "states": self.states,
            "outputs": self.outputs,
            "inputs": self.inputs,
            "ticks": self.ticks,
            "misses": self.misses,
            "stall_misses": self.stall_misses,
            "stalled_ticks": self.stalled,
            "round_trip": percentiles(&self.round_trip),
            "tick_lateness": percentiles(&self.tick_lateness),
            "tick_to_command": percentiles(&self.tick_to_command),
            "observer_compute": percentiles(&self.observer_compute),
            "controller_compute": percentiles(&self.controller_compute),
            "cpu_ns_per_sample": per_role(&self.cpu_per_sample_ns),
            "cpu_share": per_role(&self.cpu_share),
        })
    }
}

pub fn sweep(args: Vec<OsString>) -> Result<i32, String> {
    let o = Options::parse(args)?;
    let root = o
        .out
        .clone()
        .unwrap_or_else(|| crate::stamped_run_dir("sweep"));
    std::fs::create_dir_all(&root).map_err(|e| format!("{}: {e}", root.display()))?;
    let base = Scenario::load(&default_scenario()?, &base_overrides(&o, BASE_RATE_HZ))
        .map_err(|e| e.to_string())?;
    let profile = crate::bench::profile_line(&base);
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
            return Err("interrupted".into());
        }
        eprintln!("flexloop bench --sweep: {} ({})", point.label, point.what);
        let outcome = run_point(&point, &o, &root);
        if let Err(e) = &outcome {
            eprintln!("flexloop bench --sweep: {}: {e}", point.label);
        }
        results.push((point, outcome));
    }
    let floors = if o.probes {
        let samples = (BASE_RATE_HZ * 2.0) as u64;
        Some(
            probes::Floors::measure(&base, &format!("flxsweep{}_", std::process::id()), samples)?
                .json(),
        )
    } else {
        None
    };
    let text = tables(&results, floors.as_ref());
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

fn default_scenario() -> Result<PathBuf, String> {
    crate::resolve_scenario(None)
}

fn named_scenario(name: &str) -> Result<PathBuf, String> {
    let path = crate::resolve_scenario(Some(PathBuf::from(name)))?;
    if path.is_file() {
        Ok(path)
    } else {
        Err(format!("scenario `{name}` not found in scenarios/"))
    }
}

fn base_overrides(o: &Options, rate_hz: f64) -> Overrides {
    Overrides {
        rate_hz: Some(rate_hz),
        duration_s: Some(o.duration_s),
        mode: Some(Mode::Realtime),
        no_realtime: o.no_realtime,
    }
}

/// The runs, in order.
fn plan(o: &Options, root: &Path) -> Result<Vec<Point>, String> {
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
        let text =
            std::fs::read_to_string(&chain).map_err(|e| format!("{}: {e}", chain.display()))?;
        for &states in &o.states {
            let nodes = states / 2;
            let file = root.join(format!("uniform-chain-{nodes}.toml"));
            std::fs::write(&file, with_nodes(&text, nodes))
                .map_err(|e| format!("{}: {e}", file.display()))?;
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

fn run_point(point: &Point, o: &Options, root: &Path) -> Result<Measured, String> {
    let run_dir = root.join(&point.label);
    let args = LoopArgs {
        scenario: point.scenario.clone(),
        overrides: base_overrides(o, point.rate_hz),
        run_dir: Some(run_dir.clone()),
        probes: false,
        swap_every_s: None,
    };
    let prepared = prepare(&args)?;
    let design = LoopDesign::from_scenario(&prepared.scenario).map_err(|e| e.to_string())?;
    let rate_hz = prepared.scenario.timing.rate_hz;
    let mut cpu = CpuWindow::new(
        &prepared.plan.prefix,
        (o.duration_s * rate_hz * WARM_UP) as u64,
        rate_hz,
    );
    run_registered_with(prepared, |running, _| {
        cpu.observe(running);
        None
    })?;
    let summary = flexloop_node::summary::read_summary(&run_dir)?;
    let percentiles = |name: &str| {
        let v = &summary["latency"][name];
        let mut out = [0u64; 6];
        for (slot, label) in out.iter_mut().zip(QUANTILE_LABELS) {
            *slot = v[format!("{label}_ns")].as_u64().unwrap_or(0);
        }
        out
    };
    if !o.keep_logs {
        // 15–60 MB per point; the summary and the latency log stay.
        let _ = std::fs::remove_file(run_dir.join(flexloop_node::logger::SAMPLES_FILE));
    }
    // Ticks and misses as the plant counted them (the logger's count misses
    // what it could not keep up with on a busy machine).
    let own_path = run_dir.join(flexloop_node::summary::PLANT_LATENCY_FILE);
    let own: Value = std::fs::read_to_string(&own_path)
        .map_err(|e| format!("{}: {e}", own_path.display()))
        .and_then(|t| {
            serde_json::from_str(&t).map_err(|e| format!("{}: {e}", own_path.display()))
        })?;
    let counter = |name: &str| own["counters"][name].as_u64().unwrap_or(0);
    let (cpu_per_sample_ns, cpu_share) = cpu.result();
    Ok(Measured {
        states: design.observer.estimate_map.nrows(),
        outputs: design.n_outputs,
        inputs: design.n_inputs,
        ticks: own["ticks"].as_u64().unwrap_or(0),
        misses: counter("misses"),
        stall_misses: counter("stall_misses"),
        stalled: counter("stalled_ticks"),
        round_trip: percentiles("round_trip"),
        tick_lateness: percentiles("tick_lateness"),
        tick_to_command: percentiles("tick_to_command"),
        observer_compute: percentiles("observer_compute"),
        controller_compute: percentiles("controller_compute"),
        cpu_per_sample_ns,
        cpu_share,
    })
}

/// CPU time of each loop process from the first moment the logger has
/// seen the warm-up's samples (start-up, such as designing the observer of a
/// large model, takes seconds and stays out) to the last moment every loop
/// process still ran; per sample at the scenario's rate.
struct CpuWindow {
    prefix: String,
    warm_up_samples: u64,
    rate_hz: f64,
    // Field order: the inlet must drop before its node.
    inlet: Option<Inlet<Telemetry>>,
    node: Option<Node<ipc::Service>>,
    first: Option<CpuSnapshot>,
    last: Option<CpuSnapshot>,
}

#[derive(Debug, Clone)]
struct CpuSnapshot {
    at_ns: u64,
    /// (role, pid, ns on a CPU) of every running loop process.
    cpu: Vec<(Role, i32, u64)>,
}

impl CpuWindow {
    fn new(prefix: &str, warm_up_samples: u64, rate_hz: f64) -> Self {
        Self {
            prefix: prefix.to_string(),
            warm_up_samples,
            rate_hz,
            inlet: None,
            node: None,
            first: None,
            last: None,
        }
    }

    fn observe(&mut self, running: &RunningLoop) {
        if self.first.is_none() && !self.warmed_up() {
            return;
        }
        let snapshot = CpuSnapshot {
            at_ns: monotonic_ns(),
            cpu: running
                .children
                .iter()
                .filter(|c| c.exit.is_none())
                .filter_map(|c| Some((c.role, c.pid, on_cpu_ns(c.pid)?)))
                .collect(),
        };
        match &self.first {
            None => self.first = Some(snapshot),
            // Only while every process of the window's start still runs:
            // at the end the plant exits first.
            Some(first) if first.cpu.len() == snapshot.cpu.len() => self.last = Some(snapshot),
            Some(_) => {}
        }
    }

    /// Whether the logger's telemetry has counted the warm-up's samples.
    fn warmed_up(&mut self) -> bool {
        if self.inlet.is_none() {
            // The logger creates the channel; until then try again next time.
            if self.node.is_none() {
                self.node = Domain::new(&self.prefix)
                    .and_then(|d| d.node("sweep-cpu"))
                    .ok();
            }
            self.inlet = self.node.as_ref().and_then(|n| {
                Inlet::<Telemetry>::open_polling(n, &TELEMETRY, TELEMETRY.qos.loop_buffer_size).ok()
            });
        }
        let Some(inlet) = &self.inlet else {
            return false;
        };
        let mut warm = false;
        while let Ok(Some(t)) = inlet.receive() {
            warm |= t.samples >= self.warm_up_samples;
        }
        warm
    }

    /// Per role: CPU ns per sample and share of one core (NaN: no window).
    fn result(&self) -> ([f64; 4], [f64; 4]) {
        let (mut per_sample, mut share) = ([f64::NAN; 4], [f64::NAN; 4]);
        let (Some(a), Some(b)) = (&self.first, &self.last) else {
            return (per_sample, share);
        };
        let wall = b.at_ns.saturating_sub(a.at_ns).max(1) as f64;
        let samples = (wall / 1e9 * self.rate_hz).max(1.0);
        for (i, role) in Role::ALL.iter().enumerate() {
            let used: u64 = b
                .cpu
                .iter()
                .filter(|(r, _, _)| r == role)
                .filter_map(|(_, pid, end)| {
                    let (_, _, start) = a.cpu.iter().find(|(_, p, _)| p == pid)?;
                    Some(end.saturating_sub(*start))
                })
                .sum();
            per_sample[i] = used as f64 / samples;
            share[i] = used as f64 / wall;
        }
        (per_sample, share)
    }
}

/// Nanoseconds the process's threads have run on a CPU (the scheduler's own
/// account, `/proc/PID/task/*/schedstat`; getrusage only covers the dead).
fn on_cpu_ns(pid: i32) -> Option<u64> {
    let tasks = std::fs::read_dir(format!("/proc/{pid}/task")).ok()?;
    let mut total = 0u64;
    for task in tasks.flatten() {
        let text = std::fs::read_to_string(task.path().join("schedstat")).unwrap_or_default();
        total += text
            .split_whitespace()
            .next()
            .and_then(|v| v.parse::<u64>().ok())
            .unwrap_or(0);
    }
    Some(total)
}

fn us(ns: u64) -> f64 {
    ns as f64 / 1e3
}

/// Least-squares slope of log y over log x: the exponent of y ∝ x^slope.
fn growth_exponent(points: &[(f64, f64)]) -> Option<f64> {
    let logs: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && y.is_finite())
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    if logs.len() < 2 {
        return None;
    }
    let n = logs.len() as f64;
    let (mx, my) = (
        logs.iter().map(|p| p.0).sum::<f64>() / n,
        logs.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = logs.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    (sxx > 0.0).then(|| sxy / sxx)
}

/// The tables and findings as Markdown (printed, and the head of sweep.md).
fn tables(results: &[(Point, Result<Measured, String>)], floors: Option<&Value>) -> String {
    let mut t = String::new();
    let _ = writeln!(
        t,
        "\n### Latency per point (µs; misses: u(k) not there by tick k+1, stalled ticks apart)\n"
    );
    let _ = writeln!(
        t,
        "| series | point | rate kHz | states | axes | ticks | misses | per 10⁴ | stalled | round trip p50 | p99 | p99.9 | p99.99 | max | tick→u p99.99 | budget |"
    );
    let _ = writeln!(
        t,
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for (p, r) in results {
        match r {
            Ok(m) => {
                let _ = writeln!(
                    t,
                    "| {} | {} | {} | {} | {}×{} | {} | {} | {:.2} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.0} |",
                    p.series.name(),
                    p.what,
                    p.rate_hz / 1e3,
                    m.states,
                    m.outputs,
                    m.inputs,
                    m.ticks,
                    m.misses,
                    1e4 * m.miss_ratio(),
                    m.stalled,
                    us(m.round_trip[0]),
                    us(m.round_trip[2]),
                    us(m.round_trip[3]),
                    us(m.round_trip[4]),
                    us(m.round_trip[5]),
                    us(m.tick_to_command[4]),
                    1e6 / p.rate_hz
                );
            }
            Err(e) => {
                let _ = writeln!(
                    t,
                    "| {} | {} | {} | | | | | | | failed: {} | | | | | | |",
                    p.series.name(),
                    p.what,
                    p.rate_hz / 1e3,
                    e.lines().next().unwrap_or("").replace('|', "/")
                );
            }
        }
    }
    let _ = writeln!(
        t,
        "\n### Cost per point (compute: message received → published, µs; CPU: the scheduler's time per sample past start-up, µs, and share of one core)\n"
    );
    let _ = writeln!(
        t,
        "| point | observer compute p50 | p99 | controller compute p50 | p99 | CPU/sample plant | observer | controller | logger | CPU share plant | observer | controller | logger | loop CPU (plant+observer+controller) |"
    );
    let _ = writeln!(
        t,
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for (p, r) in results {
        let Ok(m) = r else { continue };
        let _ = writeln!(
            t,
            "| {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.1} % | {:.1} % | {:.1} % | {:.1} % | {:.0} % |",
            p.what,
            us(m.observer_compute[0]),
            us(m.observer_compute[2]),
            us(m.controller_compute[0]),
            us(m.controller_compute[2]),
            m.cpu_per_sample_ns[0] / 1e3,
            m.cpu_per_sample_ns[1] / 1e3,
            m.cpu_per_sample_ns[2] / 1e3,
            m.cpu_per_sample_ns[3] / 1e3,
            100.0 * m.cpu_share[0],
            100.0 * m.cpu_share[1],
            100.0 * m.cpu_share[2],
            100.0 * m.cpu_share[3],
            100.0 * m.cpu_share[..3].iter().sum::<f64>()
        );
    }
    let _ = writeln!(t, "\n### Findings\n");
    let rate_points: Vec<(&Point, &Measured)> = results
        .iter()
        .filter(|(p, _)| p.series == Series::Rate)
        .filter_map(|(p, r)| Some((p, r.as_ref().ok()?)))
        .collect();
    // The highest rate that meets the goal with the plant on its grid; the
    // rates below it that did not are named (on a shared machine a stall
    // can cost one of them its point).
    let fits = |p: &Point, m: &Measured| m.miss_ratio() < MISS_GOAL && m.keeps_the_grid(p.rate_hz);
    let highest = rate_points
        .iter()
        .filter(|(p, m)| fits(p, m))
        .map(|(p, _)| p.rate_hz)
        .fold(None, |best: Option<f64>, r| {
            Some(best.map_or(r, |b| b.max(r)))
        });
    match highest {
        Some(r) => {
            let below: Vec<String> = rate_points
                .iter()
                .filter(|(p, m)| p.rate_hz < r && !fits(p, m))
                .map(|(p, m)| {
                    format!(
                        "{} kHz ({} misses in {} ticks)",
                        p.rate_hz / 1e3,
                        m.misses,
                        m.ticks
                    )
                })
                .collect();
            let _ = writeln!(
                t,
                "- Highest rate with loop misses under 1 in 10 000 and the plant on its grid: **{} kHz**{}.",
                r / 1e3,
                if below.is_empty() {
                    String::new()
                } else {
                    format!(
                        "; below it, {} did not meet the goal in this run",
                        below.join(", ")
                    )
                }
            );
        }
        None if !rate_points.is_empty() => {
            let _ = writeln!(
                t,
                "- No rate of the sweep kept loop misses under 1 in 10 000."
            );
        }
        None => {}
    }
    for (p, m) in rate_points
        .iter()
        .filter(|(p, m)| !m.keeps_the_grid(p.rate_hz))
    {
        let _ = writeln!(
            t,
            "- At {} kHz the plant does not keep its tick grid: median wake-up {:.1} µs after the tick, more than half the {:.0} µs period (every such tick counts as stalled, its misses apart); plant, observer and controller together use {:.0} % of a CPU.",
            p.rate_hz / 1e3,
            us(m.tick_lateness[0]),
            1e6 / p.rate_hz,
            100.0 * m.cpu_share[..3].iter().sum::<f64>()
        );
    }
    let size_points: Vec<(f64, &Measured)> = results
        .iter()
        .filter(|(p, _)| p.series == Series::States)
        .filter_map(|(_, r)| r.as_ref().ok())
        .map(|m| (m.states as f64, m))
        .collect();
    let exponent = |get: &dyn Fn(&Measured) -> f64| {
        growth_exponent(
            &size_points
                .iter()
                .map(|(n, m)| (*n, get(m)))
                .collect::<Vec<_>>(),
        )
    };
    if let Some(compute) = exponent(&|m| m.observer_compute[0] as f64) {
        let mut sorted = size_points.clone();
        sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
        let top = &sorted[sorted.len().saturating_sub(2)..];
        let local = growth_exponent(
            &top.iter()
                .map(|(n, m)| (*n, m.observer_compute[0] as f64))
                .collect::<Vec<_>>(),
        );
        let _ = writeln!(
            t,
            "- Observer cost against its states (log-log slope over the uniform chains): compute p50 ∝ n^{compute:.2}{}{}{}.",
            exponent(&|m| m.cpu_per_sample_ns[1])
                .map(|c| format!(", its CPU per sample ∝ n^{c:.2}"))
                .unwrap_or_default(),
            exponent(&|m| m.controller_compute[0] as f64)
                .map(|c| format!(", controller compute p50 ∝ n^{c:.2}"))
                .unwrap_or_default(),
            local
                .filter(|_| top.len() == 2 && sorted.len() > 2)
                .map(|c| format!(
                    "; between the two largest ({} and {} states) compute p50 grows as n^{c:.2}",
                    top[0].0, top[1].0
                ))
                .unwrap_or_default()
        );
        if let Some((_, m)) = size_points.iter().max_by(|a, b| a.0.total_cmp(&b.0)) {
            let _ = writeln!(
                t,
                "- At {} states: observer compute p50 {:.2} µs, CPU {:.2} µs per sample; controller compute p50 {:.2} µs.",
                m.states,
                us(m.observer_compute[0]),
                m.cpu_per_sample_ns[1] / 1e3,
                us(m.controller_compute[0])
            );
        }
    }
    let base = [Series::Base, Series::Rate].iter().find_map(|series| {
        results.iter().find_map(|(p, r)| {
            (p.series == *series && p.rate_hz == BASE_RATE_HZ)
                .then_some(r.as_ref().ok())
                .flatten()
        })
    });
    if let Some(f) = floors {
        let _ = writeln!(
            t,
            "\n### Floors at 10 kHz (µs, measured after the runs)\n\n| probe | p50 | p99 | p99.99 | max |\n|---|---|---|---|---|"
        );
        for (key, label) in probes::Floors::ROWS {
            let v = |q: &str| f[key][format!("{q}_ns")].as_u64().unwrap_or(0);
            let _ = writeln!(
                t,
                "| {} | {:.1} | {:.1} | {:.1} | {:.1} |",
                label.trim_start_matches("probe: "),
                us(v("p50")),
                us(v("p99")),
                us(v("p99.99")),
                us(v("max"))
            );
        }
        if let Some(m) = base {
            let p50 = |key: &str| f[key]["p50_ns"].as_u64().unwrap_or(0).max(1) as f64;
            let rt = m.round_trip[0] as f64;
            let _ = writeln!(
                t,
                "\nThe loop at 10 kHz (default scenario, else thesis-mc), round trip p50 against each floor: {:.2}× the timer wake-up, {:.2}× the event ping-pong (two wake-ups, as the loop's plant → controller → plant), {:.2}× the Unix-socket ring, {:.1}× the polling ping-pong (no wake-up at all).",
                rt / p50("timer_wakeup"),
                rt / p50("iceoryx2_event_ping_pong"),
                rt / p50("unix_socket_ring"),
                rt / p50("iceoryx2_polling_ping_pong")
            );
        }
    }
    t
}

fn figures(results: &[(Point, Result<Measured, String>)]) -> Vec<(String, Figure)> {
    let ok = |series: Series| -> Vec<(&Point, &Measured)> {
        results
            .iter()
            .filter(|(p, _)| p.series == series)
            .filter_map(|(p, r)| Some((p, r.as_ref().ok()?)))
            .collect()
    };
    let mut out = Vec::new();
    let rate = ok(Series::Rate);
    if rate.len() >= 2 {
        let mut f = Figure::new(
            "sweep-rate",
            "Round trip against the sample rate (thesis-mc)",
            Axis::log10("rate [kHz]"),
            Axis::log10("latency [µs]"),
        );
        let series = |q: usize| -> Vec<(f64, f64)> {
            rate.iter()
                .map(|(p, m)| (p.rate_hz / 1e3, us(m.round_trip[q]).max(0.1)))
                .collect()
        };
        f.line("round trip p50", series(0));
        f.line("round trip p99.99", series(4));
        f.line(
            "tick → u(k) p99.99",
            rate.iter()
                .map(|(p, m)| (p.rate_hz / 1e3, us(m.tick_to_command[4]).max(0.1)))
                .collect(),
        );
        f.colored_line(
            "one sample period (the budget)",
            rate.iter()
                .map(|(p, _)| (p.rate_hz / 1e3, 1e6 / p.rate_hz))
                .collect(),
            "#d62728",
        );
        out.push(("sweep-rate.svg".to_string(), f));
    }
    let states = ok(Series::States);
    if states.len() >= 2 {
        let mut f = Figure::new(
            "sweep-states",
            "Cost against the observer's states (uniform chain, 10 kHz)",
            Axis::log10("observer states"),
            Axis::log10("time per sample [µs]"),
        );
        let line = |get: &dyn Fn(&Measured) -> f64| -> Vec<(f64, f64)> {
            states
                .iter()
                .map(|(_, m)| (m.states as f64, get(m).max(0.01)))
                .collect()
        };
        f.line("observer CPU", line(&|m| m.cpu_per_sample_ns[1] / 1e3));
        f.line("controller CPU", line(&|m| m.cpu_per_sample_ns[2] / 1e3));
        f.line("plant CPU", line(&|m| m.cpu_per_sample_ns[0] / 1e3));
        f.line("observer compute p50", line(&|m| us(m.observer_compute[0])));
        f.line("round trip p50", line(&|m| us(m.round_trip[0])));
        out.push(("sweep-states.svg".to_string(), f));
    }
    let axes: Vec<(&Point, &Measured)> = ok(Series::Base)
        .into_iter()
        .chain(ok(Series::Axes))
        .collect();
    if axes.len() >= 2 {
        let mut f = Figure::new(
            "sweep-axes",
            "Cost against the number of axes (10 kHz: SISO chain, 2×2, 3-DOF OAT-like)",
            Axis::linear("axes (inputs)"),
            Axis::log10("µs"),
        );
        let line = |get: &dyn Fn(&Measured) -> f64| -> Vec<(f64, f64)> {
            let mut v: Vec<(f64, f64)> = axes
                .iter()
                .map(|(_, m)| (m.inputs as f64, get(m).max(0.01)))
                .collect();
            v.sort_by(|a, b| a.0.total_cmp(&b.0));
            v
        };
        f.line("round trip p50", line(&|m| us(m.round_trip[0])));
        f.line("round trip p99.99", line(&|m| us(m.round_trip[4])));
        f.line(
            "observer CPU per sample",
            line(&|m| m.cpu_per_sample_ns[1] / 1e3),
        );
        f.line(
            "controller CPU per sample",
            line(&|m| m.cpu_per_sample_ns[2] / 1e3),
        );
        out.push(("sweep-axes.svg".to_string(), f));
    }
    out
}

fn write_results(
    root: &Path,
    o: &Options,
    results: &[(Point, Result<Measured, String>)],
    floors: Option<&Value>,
    text: &str,
) -> Result<(), String> {
    let write = |name: &str, bytes: &[u8]| {
        let path = root.join(name);
        let partial = root.join(format!(".{name}.partial"));
        std::fs::write(&partial, bytes)
            .and_then(|_| std::fs::rename(&partial, &path))
            .map_err(|e| format!("{}: {e}", path.display()))
    };
    let mut markdown = format!(
        "# flexloop bench --sweep\n\n{} s per point, realtime{}; host {} CPUs.\n{text}\n",
        o.duration_s,
        if o.no_realtime {
            " without real-time settings"
        } else {
            ""
        },
        flexloop_runtime::realtime::online_cpus()
    );
    for (name, figure) in figures(results) {
        write(&name, figure.to_svg().as_bytes())?;
        let _ = writeln!(markdown, "![{name}]({name})\n");
    }
    write("sweep.md", markdown.as_bytes())?;
    let points: Vec<Value> = results
        .iter()
        .map(|(p, r)| {
            json!({
                "series": p.series.name(),
                "label": p.label,
                "what": p.what,
                "rate_hz": p.rate_hz,
                "scenario": p.scenario.display().to_string(),
                "result": match r {
                    Ok(m) => m.json(),
                    Err(e) => json!({ "error": e }),
                },
            })
        })
        .collect();
    let document = json!({
        "duration_s_per_point": o.duration_s,
        "points": points,
        "floors": floors,
    });
    let pretty = serde_json::to_string_pretty(&document).map_err(|e| e.to_string())?;
    write("sweep.json", pretty.as_bytes())?;
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
    fn the_growth_exponent_of_a_power_law_is_its_power() {
        let points: Vec<(f64, f64)> = [16.0, 32.0, 64.0, 128.0]
            .iter()
            .map(|n: &f64| (*n, 3.0 * n.powf(1.7)))
            .collect();
        assert!((growth_exponent(&points).unwrap() - 1.7).abs() < 1e-12);
        assert_eq!(growth_exponent(&points[..1]), None);
    }

    #[test]
    fn the_chain_copy_has_the_nodes_asked_for() {
        let text = "name = \"u\"\n[plant]\nmodel = \"uniform-chain\"\nnodes = 32\n[observer]\nnodes_x = 1\n";
        let copy = with_nodes(text, 8);
        assert!(copy.contains("\nnodes = 8\n") && !copy.contains("nodes = 32"));
        assert!(copy.contains("nodes_x = 1"));
    }

    #[test]
    fn bad_lists_name_their_flag() {
        let parse = |v: &[&str]| Options::parse(v.iter().map(OsString::from).collect());
        assert!(
            parse(&["--sweep", "--states", "15"])
                .unwrap_err()
                .contains("--states")
        );
        assert!(
            parse(&["--sweep", "--states", "256"])
                .unwrap_err()
                .contains("--states")
        );
        assert!(
            parse(&["--sweep", "--rates", "0"])
                .unwrap_err()
                .contains("--rates")
        );
        assert!(
            parse(&["--sweep", "--series", "rate,size"])
                .unwrap_err()
                .contains("size")
        );
        let o = parse(&["--sweep", "--series", "states", "--states", "16,128"]).unwrap();
        assert_eq!((o.series, o.states), (vec![Series::States], vec![16, 128]));
    }
}
