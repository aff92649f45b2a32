//! `flexloop export RUN --csv [--out DIR]`: a run's sample file as one CSV
//! per channel, for spreadsheets and MATLAB (`readtable`).
//!
//! One header row (field names, units in parentheses), then one row per
//! message in file order. The first column is the tick's time `seq · Ts`.
//! Arrays keep the entries the run uses (`y[0]` … up to the messages'
//! `n_outputs`, x̂ up to `n_states`, the observer's feedthrough table as its
//! used rows and columns `direct[i][j]`); everything else is as recorded.

use anyhow::{Context, bail};
use flexloop_analysis::run_log::JoinedLog;
use flexloop_protocol::layout::{self, Field, MessageLayout, Scalar};
use flexloop_recording::{EventMessage, LogReader};
use flexloop_runfiles::RunDir;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// `export RUN --csv [--out DIR]`.
#[derive(Debug, clap::Args)]
pub struct ExportArgs {
    /// A run directory (every logger generation's samples*.mcap, joined in
    /// order) or one samples*.mcap file
    run: PathBuf,
    /// One CSV per channel (the only format)
    #[arg(long)]
    csv: bool,
    /// Where the CSV files go [default: RUN/csv]
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

pub fn export(args: ExportArgs) -> anyhow::Result<i32> {
    let ExportArgs { run, csv, out } = args;
    if !csv {
        bail!("export needs a format: --csv (the only one)");
    }
    let (joined, default_out) = read_run(&run)?;
    for (file, error) in &joined.torn {
        eprintln!(
            "flexloop export: {} is unfinished ({error}); exporting the complete chunks it holds",
            file.display()
        );
    }
    if let Some(what) = joined.describe() {
        eprintln!("flexloop export: {what}");
    }
    let log = &joined.log;
    let period_s = log
        .meta("period_ns")
        .and_then(|p| p.parse::<f64>().ok())
        .map(|ns| ns * 1e-9)
        .with_context(|| format!("{}: metadata `period_ns` missing", run.display()))?;
    let out = out.unwrap_or(default_out);
    std::fs::create_dir_all(&out).with_context(|| out.display().to_string())?;
    let tables: [(&str, MessageLayout, Vec<&[u8]>); 3] = [
        (
            "measurement",
            layout::MEASUREMENT,
            log.measurements().map(as_bytes).collect(),
        ),
        (
            "estimate",
            layout::ESTIMATE,
            log.estimates().map(as_bytes).collect(),
        ),
        (
            "command",
            layout::COMMAND,
            log.commands().map(as_bytes).collect(),
        ),
    ];
    for (name, layout, rows) in &tables {
        let path = out.join(format!("{name}.csv"));
        write_messages(&path, layout, rows, period_s)
            .with_context(|| path.display().to_string())?;
        let gaps = joined.gaps.get(
            flexloop_runfiles::summary::PerChannel::NAMES
                .iter()
                .position(|n| n == name)
                .expect("a channel"),
        );
        if gaps == 0 {
            println!("{} ({} rows)", path.display(), rows.len());
        } else {
            println!(
                "{} ({} rows; {gaps} samples not recorded, gap events in events.csv)",
                path.display(),
                rows.len()
            );
        }
    }
    let path = out.join("events.csv");
    write_events(&path, log).with_context(|| path.display().to_string())?;
    println!("{} ({} rows)", path.display(), log.events.len());
    Ok(0)
}

/// The sample files a RUN argument names, read as one log, and where its
/// CSVs go by default.
fn read_run(run: &Path) -> anyhow::Result<(JoinedLog, PathBuf)> {
    if run.is_dir() {
        let joined = JoinedLog::open(run)?;
        return Ok((joined, RunDir::new(run).csv()));
    }
    if run.is_file() {
        let stem = run
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "samples".into());
        let parent = run.parent().unwrap_or(Path::new("."));
        return Ok((
            JoinedLog::open_file(run)?,
            parent.join(format!("{stem}-{}", RunDir::CSV)),
        ));
    }
    bail!("{}: no such run directory or sample file", run.display())
}

fn as_bytes<T: Copy>(value: &T) -> &[u8] {
    // SAFETY: the messages are #[repr(C)] plain data without padding (see
    // flexloop_protocol::layout), so all their bytes are initialised.
    unsafe { std::slice::from_raw_parts((value as *const T).cast::<u8>(), size_of::<T>()) }
}

fn scalar_at(bytes: &[u8], scalar: Scalar, offset: usize) -> Number {
    let at = |n: usize| &bytes[offset..offset + n];
    match scalar {
        Scalar::U64 => Number::Int(u64::from_ne_bytes(at(8).try_into().expect("8 bytes"))),
        Scalar::U32 => Number::Int(u64::from(u32::from_ne_bytes(
            at(4).try_into().expect("4 bytes"),
        ))),
        Scalar::F64 => Number::Float(f64::from_ne_bytes(at(8).try_into().expect("8 bytes"))),
    }
}

enum Number {
    Int(u64),
    Float(f64),
}

impl std::fmt::Display for Number {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Number::Int(v) => write!(f, "{v}"),
            // Shortest round-trip form, with an exponent for tiny and huge values.
            Number::Float(v) => write!(f, "{v:?}"),
        }
    }
}

/// The largest count field `name` takes over `rows` (0 without the field).
fn max_count(layout: &MessageLayout, rows: &[&[u8]], name: &str) -> usize {
    let Some(field) = layout.field(name) else {
        return 0;
    };
    rows.iter()
        .map(|b| match scalar_at(b, field.scalar, field.offset) {
            Number::Int(v) => v as usize,
            Number::Float(_) => 0,
        })
        .max()
        .unwrap_or(0)
}

fn write_messages(
    path: &Path,
    layout: &MessageLayout,
    rows: &[&[u8]],
    period_s: f64,
) -> std::io::Result<()> {
    let outputs = max_count(layout, rows, "n_outputs");
    let inputs = max_count(layout, rows, "n_inputs");
    let states = max_count(layout, rows, "n_states");
    // Every column: the field and the array index it reads.
    let columns: Vec<(&Field, usize, String)> = layout
        .fields
        .iter()
        .flat_map(|f| {
            (0..layout::used_len(f, outputs, inputs, states)).map(move |i| {
                let name = layout::element_name(f, i, outputs, inputs);
                let header = if f.unit.is_empty() {
                    name
                } else {
                    format!("{name} ({})", f.unit)
                };
                (f, layout::element_index(f, i, outputs, inputs), header)
            })
        })
        .collect();
    let seq = layout.field("seq").expect("every message has a seq");
    let mut out = BufWriter::new(std::fs::File::create(path)?);
    write!(out, "t (s)")?;
    for (_, _, header) in &columns {
        write!(out, ",{header}")?;
    }
    writeln!(out)?;
    for row in rows {
        let Number::Int(k) = scalar_at(row, seq.scalar, seq.offset) else {
            unreachable!("seq is an integer");
        };
        write!(out, "{:?}", k as f64 * period_s)?;
        for (field, index, _) in &columns {
            let offset = field.offset + index * field.scalar.size();
            write!(out, ",{}", scalar_at(row, field.scalar, offset))?;
        }
        writeln!(out)?;
    }
    out.into_inner().map_err(|e| e.into_error())?.sync_all()
}

fn write_events(path: &Path, log: &LogReader) -> std::io::Result<()> {
    let mut out = BufWriter::new(std::fs::File::create(path)?);
    writeln!(out, "log_time (ns),source,kind,phase,seq,event (json)")?;
    for e in &log.events {
        let message = &e.message;
        let json = message.to_json().replace('"', "\"\"");
        let phase = match message {
            EventMessage::Logger(event) => event.edge().map_or("", |edge| edge.phase()),
            _ => "",
        };
        writeln!(
            out,
            "{},{},{},{},{},\"{json}\"",
            e.log_time_ns,
            message.source(),
            message.kind(),
            phase,
            message.seq().map_or(String::new(), |seq| seq.to_string()),
        )?;
    }
    out.into_inner().map_err(|e| e.into_error())?.sync_all()
}
