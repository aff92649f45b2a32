//! `flexloop report` on a lockstep run of the thesis (MC + AD, one scan):
//! the files, a self-contained page with one `<svg>` per figure, tables that
//! say what summary.json and metrics.json say, figures that are not empty,
//! and a clear error for a missing or corrupt run.

use crate::util::*;
use flexloop_plot::xml::check_well_formed;
use std::path::Path;
use std::time::Duration;

const FIGURES: usize = 9;

fn report(run: &Path, extra: &[&str]) -> std::process::Output {
    let mut cmd = flexloop();
    cmd.arg("report").arg(run).args(extra);
    run_bounded(cmd, Duration::from_secs(120))
}

/// `flexloop run SCENARIO` in lockstep into `dir`, then its report; both
/// must succeed. The report's folder.
fn run_and_report(dir: &Path, scenario_name: &str, extra: &[&str]) -> std::path::PathBuf {
    let mut cmd = flexloop();
    cmd.arg("run")
        .arg(scenario(scenario_name))
        .args(["--mode", "lockstep", "--no-realtime"])
        .args(extra)
        .arg("--run-dir")
        .arg(dir);
    let out = run_bounded(cmd, Duration::from_secs(180));
    assert!(out.status.success(), "{}", describe(&out));
    let out = report(dir, &[]);
    assert!(out.status.success(), "{}", describe(&out));
    dir.join("report")
}

/// The cells of the Markdown table row whose first cell is `name`.
fn row<'a>(md: &'a str, name: &str) -> Vec<&'a str> {
    let line = md
        .lines()
        .find(|l| l.starts_with(&format!("| {name} |")))
        .unwrap_or_else(|| panic!("no row {name} in\n{md}"));
    line.trim_matches('|').split(" | ").map(str::trim).collect()
}

fn copy_run(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap().flatten() {
        if entry.file_type().unwrap().is_file() {
            std::fs::copy(entry.path(), to.join(entry.file_name())).unwrap();
        }
    }
}

#[test]
fn report_of_a_lockstep_thesis_run_and_of_broken_ones() {
    let dir = temp_dir("report");
    let files = run_and_report(&dir, "thesis-mc-ad-redesigned", &[]);
    let md = std::fs::read_to_string(files.join("report.md")).unwrap();
    let html = std::fs::read_to_string(files.join("report.html")).unwrap();

    // One figure per plot: an SVG file beside the Markdown, linked from it,
    // and inlined in the page; each well-formed.
    let svg_files: Vec<_> = std::fs::read_dir(&files)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "svg"))
        .collect();
    assert_eq!(svg_files.len(), FIGURES, "{svg_files:?}");
    for path in &svg_files {
        let svg = std::fs::read_to_string(path).unwrap();
        check_well_formed(&svg).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let name = path.file_name().unwrap().to_str().unwrap();
        assert!(md.contains(&format!("]({name})")), "{name} not linked");
    }
    let inline: Vec<&str> = html
        .match_indices("<svg")
        .map(|(at, _)| &html[at..at + html[at..].find("</svg>").unwrap() + 6])
        .collect();
    assert_eq!(inline.len(), FIGURES);
    for svg in &inline {
        check_well_formed(svg).unwrap();
    }

    // Self-contained: nothing is fetched (the SVG namespace is a name, not a fetch).
    let page = html.replace(r#"xmlns="http://www.w3.org/2000/svg""#, "");
    for external in [
        "http:", "https:", "src=", "href=", "<link", "<script", "@import",
    ] {
        assert!(!page.contains(external), "{external} in report.html");
    }

    // Every plot has data: lockstep logs every tick, MC gives ŷ_flex, the
    // scenario scans once.
    for empty in [
        "no data",
        "no comparison",
        "no scan window",
        "no complete ticks",
    ] {
        assert!(!html.contains(empty), "a figure says {empty}");
    }

    // The latency table says what summary.json says, in µs.
    let s = summary(&dir);
    let labels = ["p50", "p90", "p99", "p99.9", "p99.99", "max"];
    for metric in [
        "round_trip",
        "tick_to_command",
        "plant_to_controller",
        "tick_lateness",
    ] {
        let cells = row(&md, metric);
        let v = s
            .latency
            .get(metric)
            .unwrap_or_else(|| panic!("no {metric} in summary.json"));
        assert_eq!(cells[1], v.count.to_string(), "{metric}");
        for (i, (label, ns)) in labels.iter().zip(v.percentiles.values()).enumerate() {
            let shown: f64 = cells[2 + i].parse().unwrap();
            let ns = ns as f64;
            assert!(
                (shown - ns / 1e3).abs() <= 0.05 + 1e-9,
                "{metric} {label}: {shown} vs {ns} ns"
            );
        }
        assert_eq!(cells[8], v.over_one_period.unwrap().to_string());
    }
    assert_eq!(row(&md, "ticks")[1], s.ticks.to_string());
    assert_eq!(row(&md, "loop misses")[1], s.counters.misses.to_string());
    assert!(
        md.contains("every histogram's count equals the summary's"),
        "{md}"
    );

    // The control table says what `flexloop run` wrote into metrics.json.
    let metrics = metrics(&dir);
    let rms_nm = metrics.control["rms_e_true_scan"].as_f64().unwrap() * 1e9;
    let shown: f64 = row(&md, "rms e_true over the scan window")[1]
        .parse()
        .unwrap();
    assert!(
        (shown - rms_nm).abs() <= 0.0005 + 1e-9,
        "{shown} vs {rms_nm}"
    );
    let u_rms = metrics.control["u"]["rms"].as_f64().unwrap();
    let shown: f64 = row(&md, "effort: rms u")[1].parse().unwrap();
    assert!((shown - u_rms).abs() <= 0.0005 + 1e-9, "{shown} vs {u_rms}");

    // --out writes elsewhere.
    let elsewhere = temp_dir("report-out");
    let out = report(&dir, &["--out", elsewhere.to_str().unwrap()]);
    assert!(out.status.success(), "{}", describe(&out));
    assert!(elsewhere.join("report.html").is_file());

    // Broken runs: the error names the file.
    let nothing = temp_dir("report-empty");
    let out = report(&nothing, &[]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("summary.json"), "{err}");

    let out = report(&nothing.join("absent"), &[]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no such run directory"));

    let corrupt_log = temp_dir("report-corrupt-log");
    copy_run(&dir, &corrupt_log);
    let samples = flexloop_runfiles::RunDir::SAMPLES;
    std::fs::write(corrupt_log.join(samples), b"not a sample log").unwrap();
    let out = report(&corrupt_log, &[]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(samples), "{err}");
    assert!(!corrupt_log.join("report").exists(), "no half report");

    // A damaged sample file: the report says what it could not read, and
    // fails when nothing of the run could be read.
    let bytes = std::fs::read(dir.join(samples)).unwrap();
    let half = bytes.len() / 2;
    // Bytes flipped all over the second half: some land in a chunk, whose CRC fails.
    let mut crc_damaged = bytes.clone();
    for at in (half..bytes.len() - 1024).step_by(4096) {
        crc_damaged[at] ^= 0xff;
    }
    let mut zero_tail = bytes.clone();
    zero_tail[half..].fill(0);
    for (case, damaged, readable) in [
        ("truncated", bytes[..half].to_vec(), true),
        ("crc", crc_damaged, true),
        ("zero-tail", zero_tail, true),
        ("header-only", bytes[..100].to_vec(), false),
        ("zeroed", vec![0; bytes.len()], false),
    ] {
        let broken = temp_dir(&format!("report-{case}"));
        copy_run(&dir, &broken);
        std::fs::write(broken.join(samples), damaged).unwrap();
        let out = report(&broken, &[]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(samples), "{case}: {err}");
        assert_eq!(out.status.success(), readable, "{case}: {}", describe(&out));
        if readable {
            assert!(
                err.contains("read up to its last intact chunk") && err.contains("covers the"),
                "{case}: {err}"
            );
        }
    }

    // A second run into the same directory would mix the two: refused,
    // naming the directory, before anything starts.
    let mut again = flexloop();
    again
        .arg("run")
        .arg(scenario("thesis-mc-ad-redesigned"))
        .args(["--mode", "lockstep", "--no-realtime", "--run-dir"])
        .arg(&*dir);
    let out = run_bounded(again, Duration::from_secs(60));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{}", describe(&out));
    assert!(
        err.contains(&dir.display().to_string()) && err.contains("earlier run"),
        "{err}"
    );

    let corrupt_hlog = temp_dir("report-corrupt-hlog");
    copy_run(&dir, &corrupt_hlog);
    std::fs::write(corrupt_hlog.join("latency.hlog"), "#comment\ngarbage\n").unwrap();
    let out = report(&corrupt_hlog, &[]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("latency.hlog"), "{err}");
    assert_clean(&dir);
}

/// The two-inertia setup measures angles and commands currents: its report
/// says µrad and A, never nm or N.
#[test]
fn a_report_of_the_two_inertia_setup_is_in_its_units() {
    let dir = temp_dir("report-two-inertia");
    let files = run_and_report(&dir, "two-inertia", &["--duration", "0.3"]);
    let md = std::fs::read_to_string(files.join("report.md")).unwrap();
    assert!(md.contains("µrad") && md.contains("| A |"), "{md}");
    assert!(!md.contains(" nm") && !md.contains("| N |"), "{md}");
    let tracking = std::fs::read_to_string(files.join("tracking-error.svg")).unwrap();
    assert!(tracking.contains("e_true [µrad]"), "{tracking}");
    let command = std::fs::read_to_string(files.join("command.svg")).unwrap();
    assert!(command.contains("input [A]"), "{command}");
    let _ = std::fs::remove_dir_all(&dir);
}
