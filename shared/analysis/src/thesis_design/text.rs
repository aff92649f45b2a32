//! The design report as aligned plain-text tables.

use super::*;
use std::fmt::Write as _;

impl DesignReport {
    /// The report as aligned plain-text tables.
    pub fn render_text(&self) -> String {
        let mut s = String::new();
        let spec = &self.spec;
        let domain = match spec.domain {
            DesignDomain::Continuous => "continuous time".to_string(),
            DesignDomain::Discrete {
                ts,
                command_deadline_s: Some(tau),
                ..
            } => format!(
                "discrete, Ts = {:.1} us ({:.1} kHz), each command applied on arrival at t_k + {:.0} us",
                ts * 1e6,
                1e-3 / ts,
                tau * 1e6
            ),
            DesignDomain::Discrete { ts, loop_delay, .. } => format!(
                "discrete, Ts = {:.1} us ({:.1} kHz), loop delay {} sample{}",
                ts * 1e6,
                1e-3 / ts,
                loop_delay,
                if loop_delay == 1 { "" } else { "s" }
            ),
        };
        let _ = writeln!(
            s,
            "Thesis design report: {domain}; output y{}; |S^I|, |S^O| <= {:.1} dB on y1..y7",
            spec.output, spec.limit_db
        );
        let _ = writeln!(s);
        let _ = writeln!(s, "Plant modes at y{}", spec.output);
        let _ = writeln!(
            s,
            "  {:>4}  {:>9}  {:>7}  {:>8}  {:>8}  role",
            "mode", "f [Hz]", "zeta", "phi_a", "phi_s"
        );
        for m in &self.modes {
            let _ = writeln!(
                s,
                "  {:>4}  {:>9.2}  {:>7.4}  {:>8.4}  {:>8.4}  {}",
                m.mode, m.frequency_hz, m.damping, m.phi_a, m.phi_s, m.role
            );
        }
        let _ = writeln!(s);
        let _ = writeln!(
            s,
            "Observer poles (MC+AD, band-pass Q=2, Qnu 1e3), continuous equivalent"
        );
        let _ = writeln!(s, "  {:>9}  {:>7}", "f [Hz]", "zeta");
        for p in &self.observer_poles {
            let _ = writeln!(s, "  {:>9.2}  {:>7.4}", p.frequency_hz, p.damping);
        }
        let _ = writeln!(s);
        let ad = &self.ad_damping;
        let _ = writeln!(
            s,
            "AD closed-loop damping (3.31) +{DAMPING_INCREASE}, band-pass Q={}, PID f_bw {:.1} Hz",
            ad.bandpass_q, ad.f_bw
        );
        let _ = writeln!(
            s,
            "  {:>4}  {:>9}  {:>9}  {:>7}  {:>8}",
            "mode", "f [Hz]", "open loop", "target", "achieved"
        );
        for m in &ad.modes {
            let achieved = m
                .achieved
                .map_or_else(|| "-".to_string(), |z| format!("{z:.4}"));
            let _ = writeln!(
                s,
                "  {:>4}  {:>9.2}  {:>9.4}  {:>7.4}  {:>8}",
                m.mode, m.frequency_hz, m.open_loop, m.target, achieved
            );
        }
        let _ = writeln!(s);
        let _ = writeln!(
            s,
            "Bandwidth (largest f_bw meeting the rule; crossover at y{})",
            spec.output
        );
        let _ = writeln!(
            s,
            "  {:<28}  {:>9}  {:>10}  {:>7}  {:>7}  {:>7}  {:>7}  {:>6}  {:>5}",
            "case",
            "f_bw [Hz]",
            "cross [Hz]",
            "thesis",
            "S^I dB",
            "S^O dB",
            "Tre dB",
            "stable",
            "worst"
        );
        for c in &self.cases {
            let f_bw = c
                .f_bw
                .map_or_else(|| format!("<{:.1}", spec.f_bw_min), |f| format!("{f:.1}"));
            let cross = c
                .crossover_hz
                .map_or_else(|| "-".to_string(), |f| format!("{f:.1}"));
            let (lo, hi) = c.thesis_crossover_hz;
            let thesis = if lo == hi {
                format!("{lo:.0}")
            } else {
                format!("{lo:.0}-{hi:.0}")
            };
            let _ = writeln!(
                s,
                "  {:<28}  {:>9}  {:>10}  {:>7}  {:>7.2}  {:>7.2}  {:>7.2}  {:>6}  {:>5}",
                c.label,
                f_bw,
                cross,
                thesis,
                c.peak_si_db,
                c.peak_so_db,
                c.peak_re_db,
                if c.stable { "yes" } else { "NO" },
                format!("y{}", c.limiting_output)
            );
        }
        s
    }
}
