//! `flexloop report` of a run whose scenario had a `[measure]`: a section
//! "Measured frequency responses" with the plant's Bode plot, the
//! sensitivity against the 6 dB rule and the loop gain's Nyquist plot, and
//! the verdict `flexloop measure` prints; when the responses cannot be
//! computed the section says why and the report is still written; a run
//! without `[measure]` has no such section.

use crate::util::*;
use flexloop_plot::xml::check_well_formed;
use std::path::Path;
use std::time::Duration;

const SECTION: &str = "Measured frequency responses";
const FIGURES: [(&str, &str); 3] = [
    (
        "measured-plant.svg",
        "Bode plot of the measured plant P against the design",
    ),
    (
        "measured-sensitivity.svg",
        "Measured sensitivity |S_i| against the design and the 6 dB rule",
    ),
    (
        "measured-loop-gain.svg",
        "Nyquist plot of the measured loop gain L_i",
    ),
];

/// `flexloop run SCENARIO --mode lockstep --no-realtime extra… --run-dir dir`.
fn run_lockstep(scenario_file: &Path, extra: &[&str], dir: &Path) {
    let mut cmd = flexloop();
    cmd.arg("run")
        .arg(scenario_file)
        .args(["--mode", "lockstep", "--no-realtime"])
        .args(extra)
        .arg("--run-dir")
        .arg(dir);
    let out = run_bounded(cmd, Duration::from_secs(300));
    assert!(out.status.success(), "{}", describe(&out));
}

/// `flexloop report dir`, which must succeed: its output.
fn report(dir: &Path) -> std::process::Output {
    let mut cmd = flexloop();
    cmd.arg("report").arg(dir);
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    out
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The page's text from the section's heading to the next heading of its
/// level.
fn section(html: &str) -> &str {
    let at = html
        .find(&format!("<h2>{SECTION}</h2>"))
        .unwrap_or_else(|| panic!("no section {SECTION}"));
    let rest = &html[at + 4..];
    &rest[..rest.find("<h2>").unwrap_or(rest.len())]
}

#[test]
fn a_measured_run_reports_its_responses_and_one_without_measure_does_not() {
    let dir = temp_dir("report-measurement");
    let run_dir = dir.join("run");
    run_lockstep(&scenario("measure-default"), &[], &run_dir);
    report(&run_dir);
    let files = run_dir.join("report");
    let html = read(&files.join("report.html"));
    let md = read(&files.join("report.md"));

    // The same verdict as `flexloop measure`, with the same peak.
    let mut cmd = flexloop();
    cmd.arg("measure").arg(&run_dir);
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    let printed = String::from_utf8_lossy(&out.stdout).into_owned();
    let line = printed
        .lines()
        .find(|l| l.starts_with("peak of |S_i|: "))
        .unwrap_or_else(|| panic!("no peak in\n{printed}"));
    let peak = line["peak of |S_i|: ".len()..]
        .split(" at ")
        .next()
        .unwrap();
    let verdict = ["keeps the 6 dB rule", "breaks the 6 dB rule"]
        .into_iter()
        .find(|v| line.ends_with(v))
        .unwrap_or_else(|| panic!("no verdict in {line}"));

    let measured = section(&html);
    assert!(
        measured.contains(&format!("peaks at {peak}")) && measured.contains(verdict),
        "{peak}, {verdict}:\n{measured}"
    );
    assert!(md.contains(&format!("## {SECTION}\n")), "{md}");
    assert!(md.contains(&format!("the loop {verdict}")), "{md}");

    // Three figures in the section, each a well-formed SVG file beside the
    // Markdown, linked from it and inlined in the page under its title.
    let inline: Vec<&str> = measured
        .match_indices("<svg")
        .map(|(at, _)| &measured[at..at + measured[at..].find("</svg>").unwrap() + 6])
        .collect();
    assert_eq!(inline.len(), FIGURES.len(), "{measured}");
    for ((file, title), svg) in FIGURES.iter().zip(&inline) {
        let title = flexloop_plot::xml::escape(title);
        assert!(
            svg.contains(&format!("-title\">{title}</title>")),
            "{title}"
        );
        check_well_formed(svg).unwrap_or_else(|e| panic!("{file}: {e}"));
        let on_disk = read(&files.join(file));
        check_well_formed(&on_disk).unwrap_or_else(|e| panic!("{file}: {e}"));
        assert!(md.contains(&format!("]({file})")), "{file} not linked");
        assert!(
            !svg.contains("no line of the measurement"),
            "{file} is empty"
        );
    }
    // The Bode plot has its model line and measured markers in both
    // panels; the Nyquist plot its −1 and the 6 dB circle.
    assert_eq!(inline[0].matches("design (plant model)").count(), 2);
    assert!(
        inline[0].matches("<circle").count() > 2 * 40,
        "{}",
        inline[0]
    );
    assert!(inline[1].contains("6 dB rule: |S| ≤ 6 dB"));
    assert!(inline[1].contains(">design<") && inline[2].contains(">design<"));
    assert!(inline[2].contains("−1, the critical point"));
    assert!(inline[2].contains("|1 + L| = 0.50: |S| = 6 dB"));

    // The table: per response and decade band, measured against the design.
    for name in ["P", "S_i", "T_i", "PS", "L_i"] {
        assert!(md.contains(&format!("| {name}: ")), "{name}\n{md}");
    }
    for band in ["1–10 Hz", "10–100 Hz", "100–1000 Hz", "1000–10000 Hz"] {
        assert!(md.contains(band), "{band}\n{md}");
    }
    assert!(md.contains(" dB, ") && md.contains("° ("), "{md}");

    // A recording cut short: the section says why there is no measurement,
    // the rest of the report is written.
    let cut = dir.join("cut");
    std::fs::create_dir_all(&cut).unwrap();
    for entry in std::fs::read_dir(&run_dir).unwrap().flatten() {
        if entry.file_type().unwrap().is_file() {
            std::fs::copy(entry.path(), cut.join(entry.file_name())).unwrap();
        }
    }
    let samples = flexloop_runfiles::RunDir::SAMPLES;
    let bytes = std::fs::read(run_dir.join(samples)).unwrap();
    std::fs::write(cut.join(samples), &bytes[..bytes.len() / 3]).unwrap();
    let out = report(&cut);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("the measured frequency responses cannot be computed"),
        "{err}"
    );
    let html = read(&cut.join("report/report.html"));
    let measured = section(&html);
    assert!(
        measured.contains("cannot be computed from this run directory")
            && measured.contains("before the measured periods did"),
        "{measured}"
    );
    assert!(!measured.contains("<svg"), "{measured}");
    assert!(html.contains("<h2>Control</h2>"));

    // Without [measure]: no such section.
    let plain = dir.join("plain");
    run_lockstep(
        &scenario("lecture-double-integrator"),
        &["--duration", "0.3"],
        &plain,
    );
    report(&plain);
    let html = read(&plain.join("report/report.html"));
    let md = read(&plain.join("report/report.md"));
    assert!(!html.contains(SECTION) && !md.contains(SECTION), "{md}");
    assert!(!plain.join("report/measured-plant.svg").exists());
}
