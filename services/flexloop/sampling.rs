//! What `flexloop bench` shows of the sampling instant (docs/benchmarks.md): when y(k)
//! was published against its tick, the interval between publications, and
//! how busy the plant's CPU was (a spinning wait costs CPU there).

use flexloop_node::summary::floor_histogram;
use flexloop_recording::LogReader;
use flexloop_runfiles::bench::{CpuBusy, SamplingJitter};
use flexloop_runtime::latency::LatencyHistogram;
use std::path::Path;

/// From the sample file's measurements; `None` without one (logger off).
pub fn jitter(samples: &Path, period_ns: u64) -> Option<SamplingJitter> {
    let log = LogReader::open(samples).ok()?;
    Some(jitter_of(
        log.measurements()
            .map(|m| (m.seq, m.tick_ns, m.published_ns)),
        period_ns,
    ))
}

/// `(seq, tick_ns, published_ns)` in order; intervals only between
/// consecutive sequence numbers (a gap in the recording is no interval).
fn jitter_of(samples: impl Iterator<Item = (u64, u64, u64)>, period_ns: u64) -> SamplingJitter {
    let mut after = LatencyHistogram::new();
    let mut error = LatencyHistogram::new();
    let (mut lo, mut hi) = (u64::MAX, 0);
    let mut previous: Option<(u64, u64)> = None;
    for (seq, tick, published) in samples {
        after.record_span(tick, published);
        if let Some((p_seq, p_published)) = previous
            && seq == p_seq + 1
        {
            let interval = published.saturating_sub(p_published);
            error.record(interval.abs_diff(period_ns));
            lo = lo.min(interval);
            hi = hi.max(interval);
        }
        previous = Some((seq, published));
    }
    SamplingJitter {
        published_after_tick: floor_histogram(&after),
        interval_error: floor_histogram(&error),
        interval_min_ns: if lo == u64::MAX { 0 } else { lo },
        interval_max_ns: hi,
    }
}

/// One CPU's jiffies from /proc/stat: (busy, all).
#[derive(Debug, Clone, Copy)]
pub struct CpuTimes {
    cpu: usize,
    busy: u64,
    all: u64,
}

impl CpuTimes {
    /// Now; `None` where /proc/stat has no such CPU.
    pub fn read(cpu: usize) -> Option<Self> {
        let text = std::fs::read_to_string("/proc/stat").ok()?;
        parse_cpu_line(&text, cpu)
    }

    /// The busy share from `self` to `later`.
    pub fn busy_until(&self, later: &CpuTimes) -> CpuBusy {
        let all = later.all.saturating_sub(self.all);
        let busy = later.busy.saturating_sub(self.busy);
        CpuBusy {
            cpu: self.cpu,
            share: if all == 0 {
                f64::NAN
            } else {
                busy as f64 / all as f64
            },
        }
    }
}

/// `cpuN user nice system idle iowait irq softirq steal guest guest_nice`:
/// busy is everything but idle and iowait (guest time is inside user).
fn parse_cpu_line(text: &str, cpu: usize) -> Option<CpuTimes> {
    let name = format!("cpu{cpu}");
    let line = text
        .lines()
        .find(|l| l.split_whitespace().next() == Some(name.as_str()))?;
    let v: Vec<u64> = line
        .split_whitespace()
        .skip(1)
        .take(8)
        .map(|f| f.parse().unwrap_or(0))
        .collect();
    if v.len() < 8 {
        return None;
    }
    let all: u64 = v.iter().sum();
    Some(CpuTimes {
        cpu,
        busy: all - v[3] - v[4],
        all,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jitter_counts_every_sample_and_intervals_only_between_neighbours() {
        // Period 100: published 3, 5, 2 after the tick; seq 3 is missing.
        let j = jitter_of(
            [
                (0, 1000, 1003),
                (1, 1100, 1105),
                (2, 1200, 1202),
                (4, 1400, 1410),
            ]
            .into_iter(),
            100,
        );
        assert_eq!(j.published_after_tick.count, 4);
        assert_eq!(j.interval_error.count, 2);
        assert_eq!((j.interval_min_ns, j.interval_max_ns), (97, 102));
    }

    #[test]
    fn busy_share_leaves_idle_and_iowait_out() {
        let before =
            "cpu  1 1 1 1 1 1 1 1 0 0\ncpu0 10 0 10 70 10 0 0 0 0 0\ncpu1 1 1 1 1 1 1 1 1 0 0\n";
        let after =
            "cpu  1 1 1 1 1 1 1 1 0 0\ncpu0 40 0 20 100 10 0 0 0 0 0\ncpu1 1 1 1 1 1 1 1 1 0 0\n";
        let a = parse_cpu_line(before, 0).unwrap();
        let b = parse_cpu_line(after, 0).unwrap();
        assert_eq!(a.busy_until(&b).share, 40.0 / 70.0);
        assert!(parse_cpu_line(before, 2).is_none());
    }
}
