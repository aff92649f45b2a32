//! `flexloop report` of a run whose scenario had a `[measure]`: a section
//! "Measured frequency responses" with the plant's Bode plot, the
//! sensitivity against the 6 dB rule and the loop gain's Nyquist plot, and
//! the verdict `flexloop measure` prints; when the responses cannot be
//! computed the section says why and the report is still written; a run
//! without `[measure]` has no such section. A measurement ordered on the
//! running loop gets a subsection of its own beside the scenario's, with
//! figures of its own.

use crate::util::*;
use flexloop_plot::xml::check_well_formed;
use flexloop_runfiles::events::EventKind;
use std::collections::BTreeSet;
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

/// A short measurement (periods of 20 ms, 20 lines from 50 Hz): the
/// scenario's and the ordered one's fields.
const SHORT: [&str; 7] = [
    "point=\"plant-input\"",
    "f_min_hz=50",
    "f_max_hz=2000",
    "lines=20",
    "amplitude=200",
    "transient_periods=1",
    "periods=3",
];

/// The measured section's text from the subsection `heading` (as the page
/// writes it) to the next subsection.
fn subsection<'a>(measured: &'a str, heading: &str) -> &'a str {
    let at = measured
        .find(&format!("<h3>{heading}</h3>"))
        .unwrap_or_else(|| panic!("no subsection {heading} in\n{measured}"));
    let rest = &measured[at + 4..];
    &rest[..rest.find("<h3>").unwrap_or(rest.len())]
}

/// The SVG figures inlined in `html`.
fn inlined(html: &str) -> Vec<&str> {
    html.match_indices("<svg")
        .map(|(at, _)| &html[at..at + html[at..].find("</svg>").unwrap() + 6])
        .collect()
}

#[test]
fn a_measurement_ordered_on_a_running_loop_has_its_own_subsection_and_figures() {
    let dir = temp_dir("report-ordered");
    // The measured loop with a short [measure] of its own, in lockstep until
    // stopped: the scenario's measurement ends at tick 1500.
    let file = dir.join("short.toml");
    let text = read(&scenario("measure-default"));
    let (loop_only, _) = text.split_once("[measure]").unwrap();
    let table = SHORT.join("\n").replace('=', " = ");
    std::fs::write(
        &file,
        format!("{loop_only}[measure]\n{table}\nstart_s = 0.05\n"),
    )
    .unwrap();
    let (up, prefix) = start_file_and_await(&dir, &file, &["--mode", "lockstep"], 2_000);
    let mut order = flexloop();
    order
        .args(["measure", "--running", "--prefix", &prefix])
        .args(SHORT);
    let out = run_bounded(order, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    stop(&prefix, up);
    let start = events(&dir)
        .into_iter()
        .find_map(|e| match e.kind {
            EventKind::Measure(m) => Some(m.outcome.start_seq),
            _ => None,
        })
        .expect("a measure event");
    let label = format!("at-{start}");

    report(&dir);
    let files = dir.join("report");
    let html = read(&files.join("report.html"));
    let md = read(&files.join("report.md"));
    let measured = section(&html);
    let scenarios_heading = flexloop_plot::xml::escape("The scenario's [measure]");
    let scenarios = subsection(measured, &scenarios_heading);
    let ordered = subsection(measured, &format!("Ordered at tick {start}"));
    assert!(
        measured.find(&scenarios_heading) < measured.find("Ordered at tick"),
        "{measured}"
    );
    assert!(
        md.contains(&format!("### Ordered at tick {start}\n")),
        "{md}"
    );

    // Each subsection: its three figures, files of its own, linked from the
    // Markdown; the section's element ids all differ.
    for (words, suffix) in [(scenarios, String::new()), (ordered, format!("-{label}"))] {
        let svgs = inlined(words);
        assert_eq!(svgs.len(), FIGURES.len(), "{words}");
        for ((file, title), svg) in FIGURES.iter().zip(&svgs) {
            let file = file.replace(".svg", &format!("{suffix}.svg"));
            let id = file.trim_end_matches(".svg");
            let title = flexloop_plot::xml::escape(title);
            assert!(
                svg.contains(&format!("<title id=\"{id}-title\">{title}</title>")),
                "{file}: {title}"
            );
            check_well_formed(&read(&files.join(&file))).unwrap_or_else(|e| panic!("{file}: {e}"));
            assert!(md.contains(&format!("]({file})")), "{file} not linked");
            assert!(
                !svg.contains("no line of the measurement"),
                "{file} is empty"
            );
        }
    }
    let mut ids = BTreeSet::new();
    for (at, _) in measured.match_indices(" id=\"") {
        let id = &measured[at + 5..];
        let id = &id[..id.find('"').unwrap()];
        assert!(ids.insert(id), "id {id} twice in the section");
    }
    assert!(
        ordered.contains(&format!("ordered at tick {start}"))
            && ordered.contains(&format!("measurement/{label}/frf.csv")),
        "{ordered}"
    );

    // The ordered measurement's verdict is the one `flexloop measure` prints
    // for it from the run directory.
    let mut cmd = flexloop();
    cmd.arg("measure").arg(&*dir);
    let out = run_bounded(cmd, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    let printed = String::from_utf8_lossy(&out.stdout).into_owned();
    let (_, its) = printed
        .split_once(&format!("measurement {label}:"))
        .unwrap_or_else(|| panic!("no {label} in\n{printed}"));
    let line = its
        .lines()
        .find(|l| l.starts_with("peak of |S_i|: "))
        .unwrap_or_else(|| panic!("no peak in\n{printed}"));
    let peak = line["peak of |S_i|: ".len()..]
        .split(" at ")
        .next()
        .unwrap();
    assert!(
        ordered.contains(&format!("peaks at {peak}")),
        "{peak}:\n{ordered}"
    );

    // An ordered measurement whose table does not read: its subsection says
    // why, naming the file. (Without the scenario's [measure] in this copy:
    // drawing it again would only double the report's time.)
    let damaged = dir.join("damaged");
    std::fs::create_dir_all(&damaged).unwrap();
    for entry in std::fs::read_dir(&*dir).unwrap().flatten() {
        if entry.file_type().unwrap().is_file() {
            std::fs::copy(entry.path(), damaged.join(entry.file_name())).unwrap();
        }
    }
    let copy = damaged.join(flexloop_runfiles::RunDir::SCENARIO_COPY);
    std::fs::write(&copy, format!("{loop_only}\n")).unwrap();
    let events_file = flexloop_runfiles::RunDir::EVENTS;
    let lines: String = events(&dir)
        .into_iter()
        .map(|mut e| {
            if let EventKind::Measure(m) = &mut e.kind {
                m.outcome.table = m.outcome.table.replace("f_min_hz", "f_lowest_hz");
            }
            serde_json::to_string(&e).unwrap() + "\n"
        })
        .collect();
    std::fs::write(damaged.join(events_file), lines).unwrap();
    let out = report(&damaged);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(&format!(
            "the measured frequency responses of the measurement ordered at tick {start} cannot \
             be computed"
        )),
        "{err}"
    );
    let html = read(&damaged.join("report/report.html"));
    let measured = section(&html);
    let ordered = subsection(measured, &format!("Ordered at tick {start}"));
    assert!(
        ordered.contains("cannot be computed from this run directory")
            && ordered.contains(events_file)
            && ordered.contains("f_lowest_hz"),
        "{ordered}"
    );
    assert!(!ordered.contains("<svg"), "{ordered}");
    assert!(!measured.contains(&scenarios_heading), "{measured}");
}
