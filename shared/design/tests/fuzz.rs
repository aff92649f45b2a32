//! Seeded mutations of every shipped scenario through the one check every
//! command makes (`acceptance::accept_text`, what `flexloop design`, `up`,
//! `run` and `bench` call before anything starts): no panic, no hang, and
//! every refusal names the file and a field.
//!
//! `FLEXLOOP_FUZZ_CASES` sets the number of mutated files (default 320, 20
//! per shipped scenario); `FLEXLOOP_FUZZ_SEED` the seed. The counts by
//! outcome are printed (`cargo test -p flexloop-design --test fuzz -- --nocapture`).

use flexloop_design::acceptance::accept_text;
use flexloop_scenario::Overrides;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};
use toml::{Table, Value};

/// A case that takes longer is a hang (the check of one file takes well
/// under a second; the bound only turns a hang into a failure).
const HANG: Duration = Duration::from_secs(60);

/// xorshift64*: enough randomness for a reproducible test.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }

    fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.below(items.len())]
    }
}

fn shipped() -> Vec<(String, String)> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios");
    let mut files: Vec<(String, String)> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .map(|p| {
            let name = p.file_stem().unwrap().to_string_lossy().into_owned();
            (name, std::fs::read_to_string(&p).unwrap())
        })
        .collect();
    files.sort();
    files
}

/// Every dotted path of `table` (tables included), for picking a target.
fn paths(prefix: &[String], table: &Table, out: &mut Vec<Vec<String>>) {
    for (key, value) in table {
        let mut path = prefix.to_vec();
        path.push(key.clone());
        out.push(path.clone());
        if let Value::Table(inner) = value {
            paths(&path, inner, out);
        }
    }
}

/// The table holding `path`'s last key.
fn parent<'a>(table: &'a mut Table, path: &[String]) -> Option<&'a mut Table> {
    let mut t = table;
    for key in &path[..path.len() - 1] {
        t = t.get_mut(key)?.as_table_mut()?;
    }
    Some(t)
}

const EXTREMES: [f64; 9] = [
    0.0,
    -1.0,
    1e-300,
    1e300,
    -1e300,
    5e-324,
    f64::NAN,
    f64::INFINITY,
    0.5,
];

/// One mutation of `table`, described for the failure message.
fn mutate(rng: &mut Rng, table: &mut Table) -> String {
    let mut all = Vec::new();
    paths(&[], table, &mut all);
    // Fields the schema has but the file does not write get their turn too.
    let absent = [
        "plant.mass_kg",
        "plant.nodes",
        "plant.encoders",
        "plant.sensor_position",
        "plant.sensor_scan",
        "observer.flexible_modes",
        "observer.scheduling_step",
        "observer.damping_target",
        "controller.notches_hz",
        "controller.extra_delay_samples",
        "reference.direction",
        "reference.repeat_s",
        "supervision.max_restarts",
        "realtime.timer_slack_ns",
    ];
    let path: Vec<String> = if rng.below(4) == 0 {
        rng.pick(&absent).split('.').map(String::from).collect()
    } else {
        rng.pick(&all).clone()
    };
    let dotted = path.join(".");
    let Some(holder) = parent(table, &path) else {
        return format!("nothing at {dotted}");
    };
    let key = path.last().unwrap().clone();
    // Numbers weigh most: they reach validation, the other kinds mostly the parser.
    match *rng.pick(&[0, 0, 0, 1, 1, 2, 3, 4, 5, 6]) {
        // Extremes of the value's own type (a name gets an unknown one), so
        // that most reach validation; kind 1 keeps an integer an integer.
        kind @ (0 | 1) => match holder.get(&key) {
            Some(Value::String(_)) if kind == 0 => {
                let v = *rng.pick(&["magic", "", "x/../../y", "square"]);
                holder.insert(key, Value::String(v.into()));
                format!("{dotted} = {v:?}")
            }
            Some(Value::Integer(_)) | Some(Value::String(_)) => {
                let v = *rng.pick(&[0, -1, i64::MAX, i64::MIN, 1 << 40, 3, 100]);
                holder.insert(key, Value::Integer(v));
                format!("{dotted} = {v}")
            }
            _ => {
                let v = *rng.pick(&EXTREMES);
                holder.insert(key, Value::Float(v));
                format!("{dotted} = {v:?}")
            }
        },
        2 => {
            let n = *rng.pick(&[3, 100, 5000]);
            let item = match holder.get(&key) {
                Some(Value::Array(a)) if !a.is_empty() => a[0].clone(),
                _ => Value::Float(*rng.pick(&EXTREMES)),
            };
            holder.insert(key, Value::Array(vec![item; n]));
            format!("{dotted} = [{n} entries]")
        }
        3 => {
            holder.remove(&key);
            format!("{dotted} removed")
        }
        4 => {
            holder.insert(format!("{key}_typo"), Value::Integer(1));
            format!("{dotted}_typo added")
        }
        5 => {
            let v = rng
                .pick(&[
                    Value::String("NaN".into()),
                    Value::String("1e300".into()),
                    Value::Boolean(true),
                    Value::Table(Table::new()),
                    Value::Array(Vec::new()),
                ])
                .clone();
            let shown = v.to_string();
            holder.insert(key, v);
            format!("{dotted} = {shown}")
        }
        _ => match holder.get(&key).cloned() {
            Some(Value::Table(t)) => {
                holder.insert(
                    key,
                    Value::Array(vec![Value::Table(t.clone()), Value::Table(t)]),
                );
                format!("[[{dotted}]] twice")
            }
            Some(v) => {
                holder.insert(key, Value::Array(vec![v.clone(), v]));
                format!("{dotted} doubled into a list")
            }
            None => format!("nothing at {dotted}"),
        },
    }
}

/// How a case ended.
#[derive(Debug)]
enum Outcome {
    Accepted,
    Refused {
        field: Option<String>,
        message: String,
    },
}

/// A refusal's class, for the counts.
fn class(message: &str) -> &'static str {
    if message.contains("does not apply") {
        "field does not apply"
    } else if message.contains("unknown field") {
        "parse: unknown field"
    } else if message.contains("missing field") {
        "parse: missing field"
    } else if message.contains("array of tables") {
        "parse: table doubled"
    } else if message.contains("(line ") || message.contains("nested too deeply") {
        "parse: wrong type"
    } else if message.contains("must lie in")
        || message.contains("must be")
        || message.contains("at most")
        || message.contains("Nyquist")
    {
        "out of range"
    } else if message.contains("unknown ") {
        "unknown name (model, design, shape)"
    } else {
        "design: consistency, stability, limits"
    }
}

#[test]
fn mutated_scenarios_are_accepted_or_refused_by_field_without_panic_or_hang() {
    let cases: usize = std::env::var("FLEXLOOP_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(320);
    let seed: u64 = std::env::var("FLEXLOOP_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0x5eed_f1e7_100b);
    let mut rng = Rng(seed | 1);
    let files = shipped();
    let mut counts: BTreeMap<&'static str, usize> = BTreeMap::new();
    let mut slowest = (Duration::ZERO, String::new());
    for case in 0..cases {
        let (name, text) = &files[case % files.len()];
        let mut table: Table = toml::from_str(text).unwrap();
        let mutations = if rng.below(2) == 0 {
            1
        } else {
            2 + rng.below(2)
        };
        let edits: Vec<String> = (0..mutations)
            .map(|_| mutate(&mut rng, &mut table))
            .collect();
        let mutated = toml::to_string(&table).unwrap_or_else(|_| text.clone());
        let path = PathBuf::from(format!("fuzz/{name}-{case}.toml"));
        let what = format!("case {case} ({name}: {})", edits.join("; "));
        let (tx, rx) = mpsc::channel();
        let (worker_path, worker_text) = (path.clone(), mutated.clone());
        let started = Instant::now();
        std::thread::spawn(move || {
            let result = std::panic::catch_unwind(|| {
                match accept_text(&worker_path, &worker_text, &Overrides::default(), 4) {
                    Ok(_) => Outcome::Accepted,
                    Err(e) => Outcome::Refused {
                        field: e.field.clone(),
                        message: e.to_string(),
                    },
                }
            });
            let _ = tx.send(result);
        });
        let outcome = match rx.recv_timeout(HANG) {
            Ok(Ok(outcome)) => outcome,
            Ok(Err(_)) => panic!("{what} panicked:\n{mutated}"),
            Err(_) => panic!("{what} did not answer within {HANG:?}:\n{mutated}"),
        };
        let took = started.elapsed();
        if took > slowest.0 {
            slowest = (took, what.clone());
        }
        match outcome {
            Outcome::Accepted => *counts.entry("accepted").or_default() += 1,
            Outcome::Refused { field, message } => {
                let file = path.display().to_string();
                assert!(message.contains(&file), "{what}: no file in `{message}`");
                let field = field.unwrap_or_else(|| panic!("{what}: no field in `{message}`"));
                assert!(
                    !field.is_empty() && message.contains(&field),
                    "{what}: no field in `{message}`"
                );
                // A number of three hundred digits is not an answer.
                assert!(
                    !message.contains("0000000000000000"),
                    "{what}: unreadable number in `{message}`"
                );
                *counts.entry(class(&message)).or_default() += 1;
            }
        }
    }
    println!("{cases} mutated scenarios (seed {seed:#x}):");
    for (outcome, n) in &counts {
        println!("  {n:>5}  {outcome}");
    }
    println!("slowest case: {:?}, {}", slowest.0, slowest.1);
}
