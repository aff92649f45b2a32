//! `/measurement/response` of the live view (docs/live.md, "The measured
//! response"): a measurement ordered on a running lockstep loop is shown
//! while it runs, one message per measured period with the periods done
//! growing, and the last one is what `flexloop measure` computes from the
//! recording. The client is a plain WebSocket client of the Foxglove
//! protocol (tungstenite), independent of the server's crate.

use crate::util::*;
use flexloop_modelfile::{ModelArrays, VectorAs};
use flexloop_runfiles::RunDir;
use flexloop_runfiles::events::EventKind;
use serde_json::Value;
use std::io::ErrorKind;
use std::net::TcpStream;
use std::path::Path;
use std::time::{Duration, Instant};
use tungstenite::client::IntoClientRequest;
use tungstenite::http::HeaderValue;
use tungstenite::{Message, WebSocket};

const RESPONSE_TOPIC: &str = "/measurement/response";
/// Long enough for a loaded machine; a guard against a hang, not a
/// threshold the test judges.
const PATIENCE: Duration = Duration::from_secs(300);

/// The address in `live.json`, once the server listens.
fn live_address(dir: &Path, up: &mut Up) -> String {
    let since = Instant::now();
    loop {
        if let Some(out) = up.ended() {
            panic!(
                "flexloop up ended before its live view listened\n{}",
                describe(&out)
            );
        }
        if let Ok(text) = std::fs::read_to_string(RunDir::new(dir).live()) {
            let endpoint: Value = serde_json::from_str(&text).unwrap();
            return endpoint["address"].as_str().unwrap().to_string();
        }
        assert!(
            since.elapsed() < PATIENCE,
            "no live.json in {}",
            dir.display()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A Foxglove client: its socket and the channels advertised.
struct Client {
    ws: WebSocket<TcpStream>,
    channels: Vec<Value>,
}

impl Client {
    fn connect(address: &str) -> Self {
        let stream = TcpStream::connect(address).unwrap();
        let mut request = format!("ws://{address}").into_client_request().unwrap();
        request.headers_mut().insert(
            "Sec-WebSocket-Protocol",
            HeaderValue::from_static("foxglove.sdk.v1"),
        );
        let (ws, _) = tungstenite::client(request, stream).unwrap();
        ws.get_ref()
            .set_read_timeout(Some(Duration::from_millis(200)))
            .unwrap();
        Self {
            ws,
            channels: Vec::new(),
        }
    }

    /// The next message, text (JSON) or binary; None once `since` is
    /// [`PATIENCE`] ago.
    fn read(&mut self, since: Instant) -> Option<Message> {
        loop {
            match self.ws.read() {
                Ok(Message::Text(text)) => {
                    let json: Value = serde_json::from_str(text.as_str()).unwrap();
                    if json["op"] == "advertise" {
                        self.channels
                            .extend(json["channels"].as_array().unwrap().iter().cloned());
                    }
                    return Some(Message::Text(text));
                }
                Ok(message @ Message::Binary(_)) => return Some(message),
                Ok(_) => {}
                Err(tungstenite::Error::Io(e))
                    if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
                Err(e) => panic!("the live server's connection: {e}"),
            }
            if since.elapsed() > PATIENCE {
                return None;
            }
        }
    }

    fn channel(&self, topic: &str) -> Option<&Value> {
        self.channels.iter().find(|c| c["topic"] == topic)
    }

    /// Subscribes to `topics` (subscription i + 1 is topics[i]) once they
    /// are advertised.
    fn subscribe(&mut self, topics: &[&str]) {
        let since = Instant::now();
        while topics.iter().any(|t| self.channel(t).is_none()) {
            assert!(self.read(since).is_some(), "{topics:?} not advertised");
        }
        let subscriptions: Vec<Value> = topics
            .iter()
            .enumerate()
            .map(|(i, t)| serde_json::json!({"id": i + 1, "channelId": self.channel(t).unwrap()["id"]}))
            .collect();
        let request = serde_json::json!({"op": "subscribe", "subscriptions": subscriptions});
        self.ws
            .send(Message::Text(request.to_string().into()))
            .unwrap();
    }

    /// The next message of a subscription: its id and payload; None once
    /// `since` is [`PATIENCE`] ago.
    fn next_data(&mut self, since: Instant) -> Option<(u32, Vec<u8>)> {
        loop {
            if let Message::Binary(data) = self.read(since)? {
                // opcode 1 (message data), subscription id, log time, payload.
                assert_eq!(data[0], 1);
                let id = u32::from_le_bytes(data[1..5].try_into().unwrap());
                return Some((id, data[13..].to_vec()));
            }
        }
    }
}

/// The peak of the sensitivity `name` over the lines of coherence at least
/// 0.9 (`loop_measurement::MIN_COHERENCE`) in `frf.npz`.
fn npz_peak_db(frf: &ModelArrays, name: &str) -> f64 {
    let column = |c: &str| {
        frf.matrix(&format!("{name}_{c}"), VectorAs::Column)
            .unwrap()
            .iter()
            .copied()
            .collect::<Vec<f64>>()
    };
    let (re, im, coherence) = (column("re"), column("im"), column("coherence"));
    (0..re.len())
        .filter(|&i| coherence[i] >= 0.9)
        .map(|i| 10.0 * (re[i] * re[i] + im[i] * im[i]).log10())
        .fold(f64::NEG_INFINITY, f64::max)
}

#[test]
fn live_measured_response_grows_period_by_period_to_what_measure_computes() {
    let dir = temp_dir("live-measure");
    // The measured loop (scenarios/measure-default.toml) without a
    // [measure] of its own: the measurement is ordered once the client
    // listens. Lockstep: the loop never outruns the live server's queue
    // through machine stalls of its own.
    let held = dir.join("held.toml");
    let text = std::fs::read_to_string(scenario("measure-default")).unwrap();
    let (loop_only, _) = text.split_once("[measure]").unwrap();
    std::fs::write(&held, loop_only).unwrap();
    let (mut up, prefix) = start_file(
        &dir,
        &held,
        &["--mode", "lockstep", "--live", "127.0.0.1:0"],
    );
    let address = live_address(&dir, &mut up);
    let mut client = Client::connect(&address);
    client.subscribe(&[RESPONSE_TOPIC, "/latency"]);

    // Advertised as the other JSON channels are, with its JSON schema.
    let channel = client.channel(RESPONSE_TOPIC).unwrap().clone();
    assert_eq!(channel["encoding"], "json", "{channel}");
    assert_eq!(channel["schemaEncoding"], "jsonschema", "{channel}");
    assert_eq!(
        channel["schemaName"], "flexloop/MeasuredResponse",
        "{channel}"
    );
    let schema: Value = serde_json::from_str(channel["schema"].as_str().unwrap()).unwrap();
    for field in [
        "frequencies_hz",
        "responses",
        "periods_done",
        "sensitivity",
        "state",
    ] {
        assert!(
            schema["properties"].get(field).is_some(),
            "{field}: {schema}"
        );
    }

    // A /latency message comes through the routes the subscription made:
    // from then on the server hands this client every response message.
    let since = Instant::now();
    while client.next_data(since).expect("no /latency message").0 != 2 {}

    // 20 lines from 10 Hz (periods of 1 000 samples), 2 transient and 3
    // measured periods: 0.6 s of loop time.
    let mut order = flexloop();
    order
        .args(["measure", "--running", "--prefix", &prefix])
        .args([
            "point=\"plant-input\"",
            "f_min_hz=10",
            "f_max_hz=2000",
            "lines=20",
            "amplitude=200",
            "transient_periods=2",
            "periods=3",
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped());
    let measuring = order.spawn().unwrap();

    let mut messages: Vec<Value> = Vec::new();
    let since = Instant::now();
    loop {
        let Some((id, payload)) = client.next_data(since) else {
            panic!(
                "no end of the measurement on {RESPONSE_TOPIC}: {messages:#?}\nevents: {:?}\n\
                 live-server.stderr:\n{}",
                events(&dir),
                std::fs::read_to_string(dir.join("live-server.stderr")).unwrap_or_default()
            );
        };
        if id != 1 {
            continue;
        }
        let message: Value = serde_json::from_slice(&payload).unwrap();
        let state = message["state"].as_str().unwrap().to_string();
        messages.push(message);
        if state != "measuring" {
            break;
        }
    }
    let out = wait_bounded(measuring, PATIENCE);
    let printed = describe(&out);
    assert!(out.status.success(), "{printed}");
    stop(&prefix, up);

    let ordered = events(&dir)
        .into_iter()
        .find_map(|e| match e.kind {
            EventKind::Measure(m) => Some(m.outcome),
            _ => None,
        })
        .expect("a measure event");
    let label = format!("at-{}", ordered.start_seq);
    let shown = format!(
        "{}\nlive-server.stderr:\n{}",
        serde_json::to_string_pretty(&messages).unwrap(),
        std::fs::read_to_string(dir.join("live-server.stderr")).unwrap_or_default()
    );
    // One message per measured period, the periods done growing to all.
    let done: Vec<u64> = messages
        .iter()
        .map(|m| m["periods_done"].as_u64().unwrap())
        .collect();
    assert_eq!(done, [1, 2, 3], "{shown}");
    let last = messages.last().unwrap();
    assert_eq!(last["state"], "done", "{shown}");
    for m in &messages {
        assert_eq!(m["measurement"], label.as_str(), "{shown}");
        assert_eq!(m["periods_total"], 3);
        assert_eq!(m["point"], "plant-input");
        assert_eq!(m["signal"], "multisine");
        assert!(m["start_tick"].as_u64().unwrap() >= ordered.start_seq);
    }
    // Arrays over the lines, each response with the design's beside it.
    let lines = last["frequencies_hz"].as_array().unwrap().len();
    assert!((10..=20).contains(&lines), "{shown}");
    for name in ["P", "S_i", "T_i", "PS", "L_i"] {
        let r = &last["responses"][name];
        for array in [
            "magnitude_db",
            "phase_deg",
            "coherence",
            "model_magnitude_db",
            "model_phase_deg",
        ] {
            assert_eq!(
                r[array].as_array().map(Vec::len),
                Some(lines),
                "{name}.{array}"
            );
        }
    }

    // The last one is what `flexloop measure` computed from the recording.
    let sensitivity = &last["sensitivity"];
    assert_eq!(sensitivity["response"], "S_i");
    let live_db = sensitivity["peak_db"].as_f64().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let printed_db: f64 = stdout
        .lines()
        .find_map(|l| l.strip_prefix("peak of |S_i|: "))
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|db| db.parse().ok())
        .unwrap_or_else(|| panic!("no peak of |S_i| printed\n{printed}"));
    assert!(
        (live_db - printed_db).abs() <= 0.01,
        "live {live_db} dB, measure {printed_db} dB\n{printed}"
    );
    let keeps = stdout.contains("keeps the 6 dB rule");
    assert_eq!(sensitivity["keeps_6db_rule"], keeps, "{printed}");
    let frf = ModelArrays::read(&dir.join("measurement").join(&label).join("frf.npz")).unwrap();
    let recorded_db = npz_peak_db(&frf, "S_i");
    assert!(
        (live_db - recorded_db).abs() <= 1e-9,
        "live {live_db} dB, from the recording {recorded_db} dB"
    );
    eprintln!(
        "live: periods done {done:?}, |S_i| peak {live_db:.4} dB at {} Hz; measure: {printed_db} dB",
        sensitivity["peak_hz"]
    );
}
