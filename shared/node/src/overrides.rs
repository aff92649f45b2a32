//! The scenario overrides on a command line: `flexloop` parses them, hands
//! them on to every process it starts as the same flags, and each process
//! parses them back with the same type.

use flexloop_scenario::{Mode, Overrides, TickWait};
use std::ffi::OsString;

/// `--rate HZ --duration S --mode realtime|lockstep --no-realtime --tick WAIT`.
#[derive(Debug, Clone, Copy, Default, PartialEq, clap::Args)]
pub struct OverrideFlags {
    /// Sample rate in Hz (the scenario's `loop.rate_hz`).
    #[arg(long = "rate", value_name = "HZ")]
    pub rate_hz: Option<f64>,
    /// Run length in seconds, 0 until stopped (the scenario's `loop.duration_s`).
    #[arg(long = "duration", value_name = "S")]
    pub duration_s: Option<f64>,
    /// realtime (on the clock) or lockstep (flat out, bit-exact).
    #[arg(long, value_name = "realtime|lockstep", value_parser = parse_mode)]
    pub mode: Option<Mode>,
    /// Drop every SCHED_FIFO priority (tests on a shared machine).
    #[arg(long)]
    pub no_realtime: bool,
    /// How the plant waits for its tick (the scenario's `realtime.tick`).
    #[arg(long, value_name = "sleep|sleep-then-spin", value_parser = parse_tick)]
    pub tick: Option<TickWait>,
}

fn parse_tick(text: &str) -> Result<TickWait, String> {
    text.parse()
}

fn parse_mode(text: &str) -> Result<Mode, String> {
    Mode::parse(text).ok_or_else(|| format!("unknown mode `{text}`"))
}

impl OverrideFlags {
    /// The same flags as arguments of a process `flexloop` starts.
    pub fn to_args(&self) -> Vec<OsString> {
        let mut out: Vec<OsString> = Vec::new();
        if let Some(r) = self.rate_hz {
            out.extend(["--rate".into(), r.to_string().into()]);
        }
        if let Some(d) = self.duration_s {
            out.extend(["--duration".into(), d.to_string().into()]);
        }
        if let Some(m) = self.mode {
            out.extend(["--mode".into(), m.as_str().into()]);
        }
        if self.no_realtime {
            out.push("--no-realtime".into());
        }
        if let Some(t) = self.tick {
            out.extend(["--tick".into(), t.as_str().into()]);
        }
        out
    }
}

impl From<OverrideFlags> for Overrides {
    fn from(f: OverrideFlags) -> Self {
        Overrides {
            rate_hz: f.rate_hz,
            duration_s: f.duration_s,
            mode: f.mode,
            no_realtime: f.no_realtime,
            tick: f.tick,
        }
    }
}

impl From<&Overrides> for OverrideFlags {
    fn from(o: &Overrides) -> Self {
        OverrideFlags {
            rate_hz: o.rate_hz,
            duration_s: o.duration_s,
            mode: o.mode,
            no_realtime: o.no_realtime,
            tick: o.tick,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    #[command(no_binary_name = true)]
    struct Line {
        #[command(flatten)]
        overrides: OverrideFlags,
    }

    #[test]
    fn the_flags_handed_on_parse_back_to_the_same_overrides() {
        for flags in [
            OverrideFlags::default(),
            OverrideFlags {
                rate_hz: Some(2500.5),
                duration_s: Some(0.05),
                mode: Some(Mode::Lockstep),
                no_realtime: true,
                tick: Some(TickWait::SleepThenSpin),
            },
            OverrideFlags {
                mode: Some(Mode::Realtime),
                ..OverrideFlags::default()
            },
        ] {
            let back = Line::try_parse_from(flags.to_args()).unwrap().overrides;
            assert_eq!(back, flags);
            assert_eq!(OverrideFlags::from(&Overrides::from(back)), flags);
        }
        let e = Line::try_parse_from(["--mode", "fast"]).err().unwrap();
        assert!(e.to_string().contains("unknown mode `fast`"), "{e}");
        let e = Line::try_parse_from(["--tick", "spin"]).err().unwrap();
        assert!(e.to_string().contains("unknown tick wait `spin`"), "{e}");
    }
}
