//! The live view (`flexloop up --live`): real WebSocket clients
//! (tests/integration/python/live_client.py, the `websockets` package and
//! the MCAP package's ROS1 decoder) against a running loop. What they
//! receive is what the sample file of the same run holds; each client gets
//! the rate it named; clients that never read, drop their connection or
//! send garbage disturb neither the loop, nor the logger, nor the others;
//! parameters change the loop through the swap path, or are refused with
//! the reason.

use crate::util::*;
use flexloop_components::LogReader;
use flexloop_components::sample_file::EVENT_SCHEMA;
use flexloop_protocol::WireBytes;
use flexloop_protocol::layout;
use serde_json::Value;
use std::collections::HashMap;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

/// Where the loop's live server listens, once it does (`live.json`).
fn live_url(dir: &Path, up: &mut Up) -> String {
    let since = Instant::now();
    loop {
        if let Some(out) = up.ended() {
            panic!(
                "flexloop up ended before its live view listened\n{}",
                describe(&out)
            );
        }
        if let Ok(text) = std::fs::read_to_string(dir.join("live.json")) {
            let live: Value = serde_json::from_str(&text).unwrap();
            return format!("ws://{}", live["address"].as_str().unwrap());
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
    let (mut up, prefix) = start(
        &dir,
        "lecture-double-integrator",
        &[
            "--mode",
            "lockstep",
            "--rate",
            "1000",
            "--live",
            "127.0.0.1:0",
        ],
    );
    let url = live_url(&dir, &mut up);
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
    for channel in ["measurement", "estimate", "command"] {
        assert_eq!(s["gaps"][channel], 0, "{channel} gaps: {s}");
        assert_eq!(
            s["recording"]["dropped_in_logger"][channel], 0,
            "{channel}: {s}"
        );
    }
    assert_eq!(s["recording"]["state"], "complete", "{s}");
    assert_clean(&dir);
    assert!(!dir.join("live.json").exists());
}

#[test]
fn live_parameters_show_the_tunables_and_change_the_loop_with_the_token() {
    let dir = temp_dir("live-tune");
    let (mut up, prefix) = start(
        &dir,
        "default",
        &[
            "--mode",
            "lockstep",
            "--live",
            "127.0.0.1:0",
            "--live-token",
            "s3cret",
        ],
    );
    let url = live_url(&dir, &mut up);
    wait_for_ticks(&dir, 2_000);
    let seen = client("tune", &url, "60", Some("s3cret"));
    stop(&prefix, up);

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
    let sets: Vec<Value> = events(&dir)
        .into_iter()
        .filter(|e| e["kind"] == "set")
        .collect();
    assert_eq!(sets.len(), 1);
    assert_eq!(&sets[0], live_sets[0]);
    let now = scenario_now(&dir);
    assert_eq!(now["controller"]["bandwidth_hz"].as_float(), Some(35.5));
    assert_clean(&dir);
}

#[test]
fn a_read_only_live_server_refuses_every_change_of_the_loop() {
    let dir = temp_dir("live-read-only");
    let (mut up, prefix) = start(
        &dir,
        "default",
        &[
            "--mode",
            "lockstep",
            "--live",
            "127.0.0.1:0",
            "--live-read-only",
        ],
    );
    let url = live_url(&dir, &mut up);
    let seen = client("readonly", &url, "10", None);
    stop(&prefix, up);
    let set = &seen["set"];
    assert!(statuses(set).contains("read-only"), "{set}");
    assert_eq!(parameter(&set["values"], "controller.bandwidth_hz"), 43.5);
    // A client's own rate is not a change of the loop.
    assert_eq!(parameter(&seen["rate"]["values"], "live.rate_hz"), 100.0);
    assert!(events(&dir).iter().all(|e| e["kind"] != "set"));
    assert_clean(&dir);
}

#[test]
fn a_live_server_beyond_loopback_needs_the_flag_and_a_token_before_anything_starts() {
    let dir = temp_dir("live-remote");
    for (args, says) in [
        (vec!["--live", "0.0.0.0:0"], "--live-remote"),
        (vec!["--live", "0.0.0.0:0", "--live-remote"], "--live-token"),
        (vec!["--live-token", "x"], "--live"),
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
