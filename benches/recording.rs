//! The logger's throughput headroom: how fast the sample file takes one
//! second of the loop at 10 kHz (10 000 measurements, estimates and
//! commands, a chunk every 1000 ticks as the logger's 100 ms flush makes
//! them), written flat out to a file. Headroom = ticks per second written /
//! 10 000. Also prints the file's size per second of loop.
//!
//! The messages come from the in-process loop of the default scenario (the
//! thesis design: 15 observer states, the scan under way), with timestamps
//! jittered as a real run's are, so that LZ4 sees realistic data.
//!
//! `cargo bench --bench recording` (docs/benchmarks.md, "The computation of one sample: criterion").

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use flexloop_components::InProcessLoop;
use flexloop_design::LoopDesign;
use flexloop_protocol::{Command, Estimate, Measurement};
use flexloop_recording::{LogReader, Recorder, SampleWriter};
use flexloop_scenario::{Overrides, Scenario};
use std::path::{Path, PathBuf};
use std::time::Duration;

const TICKS: u64 = 10_000;
const TICKS_PER_CHUNK: u64 = 1_000;
const PERIOD_NS: u64 = 100_000;

type Tick = (Measurement, Estimate, Command);

fn jitter(k: u64, i: u64) -> u64 {
    let mut x = (k << 4 | i) ^ 0x2545_f491_4f6c_dd1d;
    x ^= x << 13;
    x ^= x >> 7;
    x ^= x << 17;
    x % 3_000
}

/// One second of the default scenario's loop, mid-scan, with timestamps.
fn one_second() -> Vec<Tick> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/default.toml");
    let scenario = Scenario::load(&path, &Overrides::default()).expect("scenarios/default.toml");
    let design = LoopDesign::from_scenario(&scenario).expect("default design");
    let mut l = InProcessLoop::new(&design).expect("default design fits the protocol");
    for _ in 0..1_000 {
        l.tick();
    }
    (0..TICKS)
        .map(|k| {
            l.tick();
            let tick = 1_000_000_000 + k * PERIOD_NS;
            let published = tick + 2_000 + jitter(k, 0);
            let mut m = l.measurement;
            (m.tick_ns, m.woke_ns, m.published_ns) = (tick, tick + 1_500, published);
            let mut e = l.estimate;
            e.source_tick_ns = tick;
            e.source_published_ns = published;
            e.received_ns = published + 4_000 + jitter(k, 1);
            e.published_ns = e.received_ns + 1_000 + jitter(k, 2);
            let mut c = l.command;
            c.tick_ns = tick;
            c.measurement_published_ns = published;
            c.received_ns = published + 3_000 + jitter(k, 3);
            c.published_ns = c.received_ns + 800 + jitter(k, 4);
            c.estimate_published_ns = e.published_ns - PERIOD_NS;
            (m, e, c)
        })
        .collect()
}

fn write_all(ticks: &[Tick], path: &Path) -> u64 {
    let _ = std::fs::remove_file(path);
    let mut r = Recorder::new(SampleWriter::create(path, 0).expect("the bench's file"));
    for (k, (m, e, c)) in ticks.iter().enumerate() {
        r.measurement(m);
        r.estimate(e);
        r.command(c);
        if (k as u64 + 1).is_multiple_of(TICKS_PER_CHUNK) {
            r.sink().flush();
        }
    }
    r.finish(0);
    let file = r.sink().finish().expect("finished");
    file.metadata().map(|m| m.len()).unwrap_or(0)
}

fn recording(c: &mut Criterion) {
    let ticks = one_second();
    let path: PathBuf =
        std::env::temp_dir().join(format!("flexloop-bench-{}.mcap", std::process::id()));
    let bytes = write_all(&ticks, &path);
    let raw =
        TICKS as usize * (size_of::<Measurement>() + size_of::<Estimate>() + size_of::<Command>());
    let log = LogReader::open(&path).expect("reads back");
    assert_eq!(log.measurements().count() as u64, TICKS);
    eprintln!(
        "sample file: {:.2} MB per second of loop at 10 kHz ({:.1} MB of messages, LZ4 ratio {:.1})",
        bytes as f64 / 1e6,
        raw as f64 / 1e6,
        raw as f64 / bytes as f64
    );
    let mut group = c.benchmark_group("recording");
    group.throughput(Throughput::Elements(TICKS));
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(10));
    group.bench_function("one_second_at_10kHz", |b| {
        b.iter(|| write_all(&ticks, &path))
    });
    group.finish();
    let _ = std::fs::remove_file(&path);
}

criterion_group!(benches, recording);
criterion_main!(benches);
