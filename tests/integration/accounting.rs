//! The run's account adds up whoever's command it was: a program's command
//! beyond the actuator's limit is clamped by the plant and counted, its
//! effort stays a number, and every tick the plant held its input is a
//! held input in `run`'s account, with a command recorded for it or not.

use crate::util::*;
use flexloop_protocol::flags;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// A scenario file in `dir` whose controller is the Python `law`.
fn program_scenario(dir: &Path, law: &str) -> PathBuf {
    let path = dir.join("law.py");
    std::fs::write(&path, law).unwrap();
    python_controller_scenario(dir, "law.toml", &path)
}

/// `flexloop run` of `file` into `run_dir`; what it printed.
fn run(file: &Path, run_dir: &Path, args: &[&str]) -> String {
    let mut cmd = flexloop();
    cmd.arg("run")
        .arg(file)
        .args(args)
        .args(["--no-realtime", "--allow-invalid", "--run-dir"])
        .arg(run_dir);
    let out = run_bounded(cmd, Duration::from_secs(180));
    assert!(out.status.success(), "{}", describe(&out));
    String::from_utf8_lossy(&out.stdout).to_string()
}

/// The number after `label` in `said`.
fn figure(said: &str, label: &str) -> u64 {
    said.split(label)
        .nth(1)
        .and_then(|rest| {
            rest.trim_start()
                .split(|c: char| !c.is_ascii_digit())
                .next()
        })
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no figure after {label:?} in:\n{said}"))
}

/// 1e300 N for samples 100..150 (lockstep: every command is applied).
#[test]
fn a_programs_commands_beyond_the_limit_are_clamped_counted_and_their_effort_is_a_number() {
    let dir = temp_dir("accounting-clamps");
    let file = program_scenario(
        &dir,
        "import flexloop\n\n\
         class Greedy(flexloop.Controller):\n\
         \x20   def step(self, m, estimate):\n\
         \x20       if 100 <= m.seq < 150:\n\
         \x20           return 1e300\n\
         \x20       return -100.0 * m.y[0]\n\n\
         flexloop.run(Greedy)\n",
    );
    let run_dir = dir.join("run");
    let said = run(
        &file,
        &run_dir,
        &["--mode", "lockstep", "--duration", "0.5"],
    );
    assert_eq!(figure(&said, "by the controller,"), 50, "{said}");
    assert_eq!(figure(&said, "refused as not finite:"), 0, "{said}");
    let infinite = said
        .split(|c: char| c.is_whitespace() || c == ',' || c == '(' || c == ')')
        .any(|word| word == "inf" || word == "-inf" || word == "NaN");
    assert!(!infinite, "the effort is a number: {said}");
    assert_clean(&run_dir);
}

/// A law that sleeps 0.3 s once: the ticks meanwhile have no command at
/// all, and are held inputs all the same (before, only the ticks with a
/// recorded command were counted: "held inputs 0" beside a held run).
#[test]
fn every_tick_the_plant_held_is_a_held_input_with_a_command_or_without() {
    let dir = temp_dir("accounting-held");
    let file = program_scenario(
        &dir,
        "import time\nimport flexloop\n\n\
         class Napping(flexloop.Controller):\n\
         \x20   def __init__(self, setup):\n\
         \x20       super().__init__(setup)\n\
         \x20       self.napped = False\n\n\
         \x20   def step(self, m, estimate):\n\
         \x20       if m.seq >= 200 and not self.napped:\n\
         \x20           self.napped = True\n\
         \x20           time.sleep(0.3)\n\
         \x20       return -100.0 * m.y[0]\n\n\
         flexloop.run(Napping)\n",
    );
    let run_dir = dir.join("run");
    let said = run(&file, &run_dir, &["--rate", "1000", "--duration", "1"]);
    let mut held = 0u64;
    flexloop_recording::LogReader::scan(&run_dir.join("samples.mcap"), |r| {
        if let flexloop_recording::sample_file::Record::Measurement(m) = r
            && m.flags & flags::HELD_INPUT != 0
        {
            held += 1;
        }
    })
    .unwrap();
    assert!(held > 0, "the nap held the plant's input");
    assert_eq!(figure(&said, "held inputs"), held, "{said}");
    assert_clean(&run_dir);
}

/// A controller that stops sending for good (asleep in its law from sample
/// 500, not restarted): the logger recorded every tick, so the commands
/// missing from there on were never sent, and they are gaps all the same
/// (samples + gaps = ticks on every channel). Before, the summary said 0
/// command gaps, and `export` blamed a logger outage.
#[test]
fn commands_a_silent_controller_never_sent_are_gaps_of_that_cause_not_a_logger_outage() {
    let dir = temp_dir("accounting-not-sent");
    let file = program_scenario(
        &dir,
        "import time\nimport flexloop\n\n\
         class Quitter(flexloop.Controller):\n\
         \x20   def step(self, m, estimate):\n\
         \x20       if m.seq >= 500:\n\
         \x20           time.sleep(3600)\n\
         \x20       return -100.0 * m.y[0]\n\n\
         flexloop.run(Quitter)\n",
    );
    let mut table: toml::Table = toml::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    table
        .entry("supervision")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()))
        .as_table_mut()
        .unwrap()
        .insert("restart".into(), toml::Value::String("never".into()));
    std::fs::write(&file, toml::to_string(&table).unwrap()).unwrap();
    let run_dir = dir.join("run");
    let mut up = flexloop();
    up.arg("up")
        .arg(&file)
        .args([
            "--no-realtime",
            "--rate",
            "1000",
            "--duration",
            "8",
            "--run-dir",
        ])
        .arg(&run_dir);
    // The silent program is killed and, not restarted, ends the run.
    let out = run_bounded(up, Duration::from_secs(180));
    assert!(!out.status.success(), "{}", describe(&out));
    let s = summary(&run_dir);
    let ticks = s.ticks;
    let commands = s.samples.command;
    assert!(commands < ticks, "{s:?}");
    assert_eq!(commands + s.gaps.command, ticks, "{s:?}");
    let mut export = flexloop();
    export.args(["export", "--csv"]).arg(&run_dir);
    let out = run_bounded(export, Duration::from_secs(120));
    assert!(out.status.success(), "{}", describe(&out));
    let events = std::fs::read_to_string(run_dir.join("csv/events.csv")).unwrap();
    assert!(!events.contains("logger-outage"), "{events}");
    assert!(events.contains("not-sent"), "{events}");
    assert_clean(&run_dir);
}
