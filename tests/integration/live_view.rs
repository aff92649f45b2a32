//! The live view (`flexloop up --live`): real WebSocket clients
//! (tests/integration/python/live_client.py, the `websockets` package and
//! the MCAP package's ROS1 decoder) against a running loop. What they
//! receive is what the sample file of the same run holds; each client gets
//! the rate it named; clients that never read, drop their connection or
//! send garbage disturb neither the loop, nor the logger, nor the others;
//! parameters change the loop through the swap path, or are refused with
//! the reason. What a client can take of the server is bounded: 16
//! connections (one more is refused at once), a message of 64 KiB, and
//! wrong tokens throttled; the token comes from the environment or a file,
//! never the command line.

use crate::util::*;
use flexloop_protocol::WireBytes;
use flexloop_protocol::layout;
use flexloop_recording::LogReader;
use flexloop_recording::sample_file::EVENT_SCHEMA;
use flexloop_runfiles::RunDir;
use flexloop_runfiles::events::SupervisorEvent;
use flexloop_runfiles::json::read_json;
use flexloop_runfiles::live::{LiveEndpoint, LiveSummary};
use serde_json::Value;
use std::collections::HashMap;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

/// A token long enough (16 characters or more).
const TOKEN: &str = "s3cret-0123456789abcdef";

/// Where the loop's live server listens, once it does (`live.json`).
fn live_url(dir: &Path, up: &mut Up) -> String {
    format!("ws://{}", live_endpoint(dir, up).address)
}

/// [`start`] with a live view on loopback (`--live 127.0.0.1:0`) and
/// `args`, once the view listens: the loop, its prefix, the view's URL.
fn start_live(dir: &Path, scenario_name: &str, args: &[&str]) -> (Up, String, String) {
    let args = [&["--live", "127.0.0.1:0"], args].concat();
    let (mut up, prefix) = start(dir, scenario_name, &args);
    let url = live_url(dir, &mut up);
    (up, prefix, url)
}

/// The live server's pid (`live.json`), once it listens.
fn live_pid(dir: &Path, up: &mut Up) -> String {
    live_endpoint(dir, up).pid.to_string()
}

/// A file holding `token`, readable by its owner only.
fn token_file(dir: &Path, name: &str, token: &str) -> std::path::PathBuf {
    use std::os::unix::fs::PermissionsExt;
    let path = dir.join(name);
    std::fs::write(&path, format!("{token}\n")).unwrap();
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).unwrap();
    path
}

/// `live_summary.json`, which the server writes when it stops.
fn live_summary(dir: &Path) -> LiveSummary {
    read_json(&RunDir::new(dir).live_summary()).unwrap_or_else(|e| panic!("{e}"))
}

/// What the live server wrote to its log.
fn live_log(dir: &Path) -> String {
    std::fs::read_to_string(dir.join("live-server.stderr")).unwrap_or_default()
}

fn live_endpoint(dir: &Path, up: &mut Up) -> LiveEndpoint {
    let since = Instant::now();
    loop {
        if let Some(out) = up.ended() {
            panic!(
                "flexloop up ended before its live view listened\n{}",
                describe(&out)
            );
        }
        let path = RunDir::new(dir).live();
        if let Ok(text) = std::fs::read_to_string(&path) {
            return serde_json::from_str(&text)
                .unwrap_or_else(|e| panic!("{}: {e}\n{text}", path.display()));
        }
        assert!(
            since.elapsed() < Duration::from_secs(90),
            "no live.json in {}",
            dir.display()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn client(scene: &str, url: &str, seconds: &str, token: Option<&str>) -> Value {
    let python = python_with(&["websockets", "mcap_ros1"]);
    let script =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/integration/python/live_client.py");
    let mut cmd = Command::new(python);
    cmd.arg(script).args([scene, url, seconds]).args(token);
    let out = run_bounded(cmd, Duration::from_secs(240));
    assert!(out.status.success(), "{}", describe(&out));
    serde_json::from_slice(&out.stdout).unwrap()
}

fn statuses(answer: &Value) -> String {
    answer["statuses"].to_string()
}

fn parameter<'a>(values: &'a Value, name: &str) -> &'a Value {
    values
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["name"] == name)
        .map_or(&Value::Null, |p| &p["value"])
}

#[test]
fn live_clients_get_the_recorded_messages_at_their_rate_and_bad_clients_disturb_nothing() {
    let dir = temp_dir("live-observe");
    // Lockstep, so that any gap would be the live server's doing: the loop
    // misses nothing of its own however loaded the machine is.
    let (up, prefix, url) = start_live(
        &dir,
        "lecture-double-integrator",
        &["--mode", "lockstep", "--rate", "1000"],
    );
    let seen = client("observe", &url, "4", None);
    let status = run_bounded(
        {
            let mut c = flexloop();
            c.args(["status", "--prefix", &prefix]);
            c
        },
        Duration::from_secs(60),
    );
    assert!(
        String::from_utf8_lossy(&status.stdout).contains("live view: ws://127.0.0.1:"),
        "{}",
        describe(&status)
    );
    let out = stop(&prefix, up);
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("live view on ws://127.0.0.1:"),
        "{}",
        describe(&out)
    );

    // Advertised with the sample file's encodings and schemas.
    let channels: HashMap<String, &Value> = seen["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| (c["topic"].as_str().unwrap().to_string(), c))
        .collect();
    for (topic, l) in [
        ("/measurement", layout::MEASUREMENT),
        ("/estimate", layout::ESTIMATE),
        ("/command", layout::COMMAND),
    ] {
        let c = channels[topic];
        assert_eq!(c["encoding"], "ros1", "{c}");
        assert_eq!(c["schemaEncoding"], "ros1msg", "{c}");
        assert_eq!(c["schemaName"], l.type_name, "{c}");
        assert_eq!(c["schema"], l.ros1_definition(), "{c}");
    }
    assert_eq!(channels["/events"]["schema"], EVENT_SCHEMA);
    for topic in ["/events", "/latency", "/scenario"] {
        assert_eq!(channels[topic]["encoding"], "json");
    }
    assert_eq!(seen["loop_rate_hz"], 1000.0);

    // Every message a client got is the sample file's message of that
    // sequence number, byte for byte (and decoded by the advertised schema).
    let log = LogReader::open(&dir.join("samples.mcap")).unwrap();
    let recorded: HashMap<(&str, u64), Vec<u8>> = log
        .measurements()
        .map(|m| (("/measurement", m.seq), m.wire_bytes().to_vec()))
        .chain(
            log.estimates()
                .map(|e| (("/estimate", e.seq), e.wire_bytes().to_vec())),
        )
        .chain(
            log.commands()
                .map(|c| (("/command", c.seq), c.wire_bytes().to_vec())),
        )
        .collect();
    let full = &seen["full"]["received"];
    for topic in ["/measurement", "/estimate", "/command"] {
        let got = &full[topic];
        assert!(got["count"].as_u64().unwrap() > 0, "{topic}: {got}");
        assert_eq!(got["in_order"], true, "{topic}");
        for kept in got["kept"].as_array().unwrap() {
            let seq = kept["seq"].as_u64().unwrap();
            let bytes: Vec<u8> = (0..kept["hex"].as_str().unwrap().len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&kept["hex"].as_str().unwrap()[i..i + 2], 16).unwrap())
                .collect();
            assert_eq!(
                recorded.get(&(topic, seq)),
                Some(&bytes),
                "{topic} seq {seq}: not the recorded message"
            );
        }
    }
    // The decimated client named rate/10: every tenth sample, the same ones
    // on each channel, and nothing of the channels it did not subscribe to.
    let named = &seen["named_rate"];
    assert_eq!(
        parameter(&named["values"], "live.rate_hz"),
        100.0,
        "{named}"
    );
    let decimated = &seen["decimated"]["received"];
    for topic in ["/measurement", "/command"] {
        let got = &decimated[topic];
        assert!(got["count"].as_u64().unwrap() > 0, "{topic}: {got}");
        assert_eq!(got["all_seqs_multiple_of"], 10, "{topic}: {got}");
    }
    assert!(decimated.get("/estimate").is_none());
    // Once a second: the logger's counters and percentiles, and the server's own.
    let latency = decimated["/latency"]["json"].as_array().unwrap();
    assert!(!latency.is_empty());
    let last = latency.last().unwrap();
    assert!(
        last["round_trip_us"]["p50"].as_f64().unwrap() > 0.0,
        "{last}"
    );
    assert!(last["live"]["clients"].as_u64().unwrap() >= 2, "{last}");
    // Each client is told how many messages the server handed to it: what
    // it received less that is what its own queue dropped, and accounts for
    // every sample missing from its full-rate streams.
    for client in [full, decimated] {
        for message in client["/latency"]["json"].as_array().unwrap() {
            let handed = message["live"]["you"]["handed"].as_u64().unwrap();
            let received = message["received_before"].as_u64().unwrap();
            let missing = message["missing_by_seq"].as_u64().unwrap();
            // (A sample the server's own reader lost was never handed.)
            let lost: u64 = ["measurement", "estimate", "command"]
                .iter()
                .map(|c| message["live"]["lost_by_reader"][c].as_u64().unwrap())
                .sum();
            assert!(
                handed >= received && handed - received + lost >= missing,
                "handed {handed}, received {received}, missing {missing}, lost by the reader {lost}"
            );
        }
    }
    // The scenario as it stands on subscribing.
    let scenario = &decimated["/scenario"]["json"][0];
    let file = scenario["file"].as_str().unwrap();
    assert_eq!(
        scenario["toml"].as_str().unwrap(),
        std::fs::read_to_string(file).unwrap(),
        "{file}"
    );
    // With the design it runs, in words (what `status` prints): the
    // lecture's state feedback on its predictor observer.
    assert_eq!(
        scenario["design"]["controller"], "state feedback",
        "{scenario}"
    );
    assert_eq!(
        scenario["design"]["observer"], "state-feedback",
        "{scenario}"
    );
    // Unsubscribed (from all but /latency): the server hands it nothing
    // more between two of its latency messages but the latency itself.
    assert_eq!(seen["handed_after_unsubscribing"], 0, "{seen}");
    // The garbage client was told, not the loop.
    assert!(
        !seen["garbage"]["statuses"].as_array().unwrap().is_empty(),
        "{}",
        seen["garbage"]
    );

    // Nothing of the loop lost anything to the clients.
    let s = summary(&dir);
    let dropped = s.recording.dropped_in_logger;
    for (channel, dropped) in [
        ("measurement", dropped.measurement),
        ("estimate", dropped.estimate),
        ("command", dropped.command),
    ] {
        assert_eq!(of_channel(&s.gaps, channel), 0, "{channel} gaps: {s:?}");
        assert_eq!(dropped, 0, "{channel}: {s:?}");
    }
    assert_eq!(s.recording.sample_file.state, "complete", "{s:?}");
    assert_clean(&dir);
    assert!(!dir.join("live.json").exists());
}

#[test]
fn live_parameters_show_the_tunables_and_change_the_loop_with_the_token() {
    let dir = temp_dir("live-tune");
    let tokens = temp_dir("live-tune-token");
    let file = token_file(&tokens, "token", TOKEN);
    let (up, prefix, url) = start_live(
        &dir,
        "default",
        &[
            "--mode",
            "lockstep",
            "--live-token-file",
            file.to_str().unwrap(),
        ],
    );
    wait_for_ticks(&dir, 2_000);
    let seen = client("tune", &url, "60", Some(TOKEN));
    let out = stop(&prefix, up);
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("changes need live.token"),
        "{}",
        describe(&out)
    );

    let all = &seen["parameters"];
    assert_eq!(parameter(all, "controller.bandwidth_hz"), 43.5, "{all}");
    assert!(parameter(all, "observer.q_nu").is_number(), "{all}");
    assert!(
        parameter(all, "supervision.estimate_watchdog_ticks").is_number(),
        "{all}"
    );

    assert_eq!(parameter(all, "supervision.safe_action"), "hold", "{all}");
    let without = &seen["without_token"];
    assert!(statuses(without).contains("live.token"), "{without}");
    assert_eq!(
        parameter(&without["values"], "controller.bandwidth_hz"),
        43.5
    );
    assert!(statuses(&seen["wrong_token"]).contains("not the server's token"));

    let with = &seen["with_token"];
    assert_eq!(
        parameter(&with["values"], "controller.bandwidth_hz"),
        35.5,
        "{with}"
    );
    assert!(statuses(with).contains("43.5 -> 35.5"), "{with}");

    let breaks = &seen["breaks_rule"];
    assert!(statuses(breaks).contains("set refused"), "{breaks}");
    assert!(statuses(breaks).contains("6 dB"), "{breaks}");
    assert_eq!(
        parameter(&breaks["values"], "controller.bandwidth_hz"),
        35.5
    );
    // What a swap may not change is refused by name (docs/architecture.md).
    let not_swappable = statuses(&seen["not_swappable"]);
    assert!(
        not_swappable.contains("set refused")
            && not_swappable.contains("loop.rate_hz")
            && not_swappable.contains("a swap may not change it"),
        "{not_swappable}"
    );
    assert!(statuses(&seen["odd_rate"]).contains("does not divide"));
    assert_eq!(parameter(&seen["after"], "controller.bandwidth_hz"), 35.5);

    // The set went through the swap path: in /events live, and in the run's files.
    let live_sets: Vec<&Value> = seen["events"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["kind"] == "set")
        .collect();
    assert_eq!(live_sets.len(), 1, "{}", seen["events"]);
    let sets = sets(&dir);
    assert_eq!(sets.len(), 1);
    // The same event: the live one read as the file's is (compared as
    // written again, since a NaN |Δu| is not equal to itself).
    let live_set: SupervisorEvent = serde_json::from_value(live_sets[0].clone())
        .unwrap_or_else(|e| panic!("{e}: {}", live_sets[0]));
    assert_eq!(
        serde_json::to_string(&sets[0]).unwrap(),
        serde_json::to_string(&live_set).unwrap()
    );
    let now = scenario_now(&dir);
    assert_eq!(now["controller"]["bandwidth_hz"].as_float(), Some(35.5));
    assert_clean(&dir);
}

#[test]
fn a_read_only_live_server_refuses_every_change_of_the_loop() {
    let dir = temp_dir("live-read-only");
    let (up, prefix, url) =
        start_live(&dir, "default", &["--mode", "lockstep", "--live-read-only"]);
    let seen = client("readonly", &url, "10", None);
    stop(&prefix, up);
    let set = &seen["set"];
    assert!(statuses(set).contains("read-only"), "{set}");
    assert_eq!(parameter(&set["values"], "controller.bandwidth_hz"), 43.5);
    // A client's own rate is not a change of the loop.
    assert_eq!(parameter(&seen["rate"]["values"], "live.rate_hz"), 100.0);
    assert!(sets(&dir).is_empty());
    assert_clean(&dir);
}

#[test]
fn a_live_server_beyond_loopback_needs_the_flag_and_a_token_before_anything_starts() {
    let dir = temp_dir("live-remote");
    for (args, says) in [
        (vec!["--live", "0.0.0.0:0"], "--live-remote"),
        (
            vec!["--live", "0.0.0.0:0", "--live-remote"],
            "FLEXLOOP_LIVE_TOKEN",
        ),
        (vec!["--live-token-file", "x"], "--live"),
    ] {
        let mut c = flexloop();
        c.args(["up", "default", "--no-realtime", "--run-dir"])
            .arg(dir.join("run"))
            .args(&args);
        let out = run_bounded(c, Duration::from_secs(60));
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}", describe(&out));
        assert!(
            String::from_utf8_lossy(&out.stderr).contains(says),
            "{args:?}: {}",
            describe(&out)
        );
        assert!(!dir.join("run").exists(), "{args:?}: a run started");
    }
}

/// `up` with `env` added to its environment and `args` after the scenario,
/// to its end (bounded); its output.
fn up_with(dir: &Path, env: &[(&str, &str)], args: &[&str]) -> std::process::Output {
    let mut c = flexloop();
    c.args([
        "up",
        "lecture-double-integrator",
        "--no-realtime",
        "--run-dir",
    ])
    .arg(dir)
    .args(args)
    .env_remove("FLEXLOOP_LIVE_TOKEN")
    .envs(env.iter().copied());
    run_bounded(c, Duration::from_secs(120))
}

#[test]
fn a_live_token_comes_from_the_environment_or_a_file_never_the_command_line() {
    let dir = temp_dir("live-token-sources");
    let short = "x".repeat(15);
    let short_file = token_file(&dir, "short", &short);
    let good_file = token_file(&dir, "good", TOKEN);
    fn with<'a>(extra: &[&'a str]) -> Vec<&'a str> {
        [&["--live", "127.0.0.1:0", "--duration", "1"][..], extra].concat()
    }
    /// The environment `up` gets, its arguments, what its refusal says.
    type Refused<'a> = (Vec<(&'a str, &'a str)>, Vec<&'a str>, &'a [&'a str]);
    let refused: [Refused; 5] = [
        // On the command line: every local user reads it in /proc/PID/cmdline.
        (
            vec![],
            with(&["--live-token", TOKEN]),
            &[
                "readable by every local user",
                "FLEXLOOP_LIVE_TOKEN",
                "--live-token-file",
            ],
        ),
        (
            vec![("FLEXLOOP_LIVE_TOKEN", &short)],
            with(&[]),
            &["FLEXLOOP_LIVE_TOKEN", "15 characters", "16"],
        ),
        (
            vec![],
            with(&["--live-token-file", short_file.to_str().unwrap()]),
            &["--live-token-file", "15 characters"],
        ),
        (
            vec![("FLEXLOOP_LIVE_TOKEN", "")],
            with(&[]),
            &["FLEXLOOP_LIVE_TOKEN", "empty"],
        ),
        (
            vec![("FLEXLOOP_LIVE_TOKEN", TOKEN)],
            with(&["--live-token-file", good_file.to_str().unwrap()]),
            &["two tokens"],
        ),
    ];
    for (env, args, says) in refused {
        let run = dir.join("refused");
        let out = up_with(&run, &env, &args);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}", describe(&out));
        let stderr = String::from_utf8_lossy(&out.stderr);
        for word in says {
            assert!(
                stderr.contains(word),
                "{args:?}: {word:?}: {}",
                describe(&out)
            );
        }
        assert!(!stderr.contains(TOKEN), "the token was printed: {stderr}");
        assert!(!run.exists(), "{args:?}: a run started");
    }
    // The environment and a file are taken: the live view then wants the token.
    for (name, env, args) in [
        ("env", vec![("FLEXLOOP_LIVE_TOKEN", TOKEN)], vec![]),
        (
            "file",
            vec![],
            vec!["--live-token-file", good_file.to_str().unwrap()],
        ),
    ] {
        let run = dir.join(name);
        let out = up_with(
            &run,
            &env,
            &[&["--live", "127.0.0.1:0", "--duration", "4"][..], &args].concat(),
        );
        assert_ran(&out);
        assert!(
            String::from_utf8_lossy(&out.stderr).contains("changes need live.token"),
            "{name}: {}",
            describe(&out)
        );
        assert!(run.join("live_summary.json").is_file(), "{name}");
    }
}

#[test]
fn live_connections_beyond_the_cap_are_refused_and_slow_clients_hold_bounded_memory() {
    let dir = temp_dir("live-flood");
    let (mut up, prefix, url) = start_live(&dir, "lecture-double-integrator", &["--rate", "1000"]);
    let pid = live_pid(&dir, &mut up);
    // Straight to the crate's own port (loopback), not through the
    // server's address: advertisements, and nothing else.
    let bypass = client("bypass", &url, "2", Some(&pid));
    assert_eq!(bypass["received"], 0, "{bypass}");
    assert_eq!(bypass["get"], serde_json::json!([]), "{bypass}");
    assert!(
        statuses(&bypass).contains("not a client of this server"),
        "{bypass}"
    );
    // 1 000 at once; the 16 admitted subscribe to everything and never
    // read, for 8 s (at 1 kHz their queues of 8 192 fill in under 3 s).
    let seen = client("flood", &url, "8", Some(&pid));
    stop(&prefix, up);
    eprintln!("flood: {seen}");
    assert_eq!(seen["admitted"], 16, "{seen}");
    let refused_503 = seen["refused_503"].as_u64().unwrap();
    let refused_otherwise = seen["refused_otherwise"].as_array().unwrap().len() as u64;
    assert_eq!(refused_503 + refused_otherwise, 1000 - 16, "{seen}");
    assert!(refused_503 >= 900, "{seen}");
    assert!(
        seen["refusal_body"]
            .as_str()
            .unwrap()
            .contains("at most 16 clients"),
        "{seen}"
    );
    assert_eq!(seen["extra_refusal"]["status"], 503, "{seen}");
    // Once they left, their places are given back.
    assert_eq!(seen["again_admitted"], true, "{seen}");
    // The server's memory: 16 full queues at most, whatever the 984 others
    // did (before: 79 MB idle, 218 MB with 1 000 idle connections, 658 MB
    // with 300 that never read).
    let kb = |v: &Value, key: &str| v[key].as_u64().unwrap() as f64;
    let before = kb(&seen["memory_before_kb"], "VmRSS");
    let peak = kb(&seen["memory_after_kb"], "VmHWM");
    eprintln!(
        "live server: {:.1} MB before, {:.1} MB at the peak, {:.1} MB during, {:.1} MB after",
        before / 1024.0,
        peak / 1024.0,
        kb(&seen["memory_during_kb"], "VmRSS") / 1024.0,
        kb(&seen["memory_after_kb"], "VmRSS") / 1024.0
    );
    assert!(
        peak - before < 72.0 * 1024.0,
        "the server grew from {before} kB to {peak} kB: {seen}"
    );
    // Counted and logged.
    let summary = live_summary(&dir);
    assert_eq!(summary.max_connections, 16, "{summary:?}");
    assert_eq!(summary.most_connections, 16, "{summary:?}");
    assert!(
        // The 984 of the flood and the one more while they held every place.
        summary.refused_connections > 1000 - 16,
        "{summary:?}"
    );
    let log = live_log(&dir);
    assert!(
        log.contains("refused") && log.contains("16 clients are connected"),
        "{log}"
    );
    assert_clean(&dir);
}

#[test]
fn live_token_guesses_are_throttled_and_a_large_set_is_refused_before_it_costs_memory() {
    let dir = temp_dir("live-guard");
    let tokens = temp_dir("live-guard-token");
    let file = token_file(&tokens, "token", TOKEN);
    let (mut up, prefix, url) = start_live(
        &dir,
        "lecture-double-integrator",
        &[
            "--rate",
            "1000",
            "--live-token-file",
            file.to_str().unwrap(),
        ],
    );
    let pid = live_pid(&dir, &mut up);
    let big = client("bigset", &url, "20", Some(&pid));
    let brute = client("brute", &url, "3", Some(TOKEN));
    stop(&prefix, up);
    eprintln!("bigset: {big}\nbrute: {brute}");

    // A set just under the 64 KiB a client may send, without the token:
    // refused for the token (its value never converted).
    assert!(statuses(&big["under"]).contains("live.token"), "{big}");
    // 15 MB: the connection is closed at the frame's header; no answer.
    assert!(big["big_closed"].is_string(), "{big}");
    assert_eq!(big["big_answered"], false, "{big}");
    assert!(big["still_served"].is_array(), "{big}");
    let kb = |v: &Value, key: &str| v[key].as_u64().unwrap() as f64;
    let (before, after) = (&big["memory_before_kb"], &big["memory_after_kb"]);
    eprintln!(
        "live server: {:.1} MB before, {:.1} MB after (peak {:.1} -> {:.1} MB)",
        kb(before, "VmRSS") / 1024.0,
        kb(after, "VmRSS") / 1024.0,
        kb(before, "VmHWM") / 1024.0,
        kb(after, "VmHWM") / 1024.0
    );
    // (Before: the 15 MB message peaked at 274 MB.)
    assert!(
        kb(after, "VmHWM") - kb(before, "VmHWM").max(kb(before, "VmRSS")) < 4.0 * 1024.0,
        "{big}"
    );
    assert!(
        kb(after, "VmRSS") - kb(before, "VmRSS") < 4.0 * 1024.0,
        "{big}"
    );

    // Wrong tokens: a handful compared, the rest refused unexamined, by the
    // server's own counts; the right one is refused while the lockout
    // holds and taken after it.
    let summary = live_summary(&dir);
    let failures = summary.token_failures;
    let throttled = summary.token_throttled;
    let wall_s = summary.wall_s;
    eprintln!(
        "{} guesses sent in {:.1} s; {failures} compared, {throttled} refused unexamined \
         over the server's {wall_s:.1} s",
        brute["sent"], brute["elapsed_s"]
    );
    assert!(failures >= 5, "{summary:?}");
    // 5 free, then one after each lockout (1, 2, 4, ... s): at most
    // 6 + log2(1 + T) in the server's T seconds.
    let bound = 6.0 + (1.0 + wall_s).log2();
    assert!(
        (failures as f64) <= bound,
        "{failures} wrong tokens compared in {wall_s} s: {summary:?}"
    );
    let sent = brute["sent"].as_u64().unwrap();
    assert!(sent > 100, "{brute}");
    assert!(failures + throttled >= sent, "{summary:?} {brute}");
    assert!(brute["throttled"].as_u64().unwrap() > 0, "{brute}");
    let during = brute["right_during"]["statuses"].as_array().unwrap();
    assert!(
        during.len() == 2 && during[1].to_string().contains("too many wrong tokens"),
        "{brute}"
    );
    assert!(
        !statuses(&brute["right_after"]).contains("live.token"),
        "{brute}"
    );
    // Logged, and counted in the summary.
    let log = live_log(&dir);
    assert!(log.contains("a wrong live.token"), "{log}");
    assert!(log.contains("refused unexamined"), "{log}");
    assert!(log.contains("at most 65536 bytes"), "{log}");
    assert!(summary.oversized_messages >= 1, "{summary:?}");
    assert!(sets(&dir).is_empty());
    assert_clean(&dir);
}
