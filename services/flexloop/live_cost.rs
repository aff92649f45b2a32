//! `flexloop bench --live-cost`: the same loop run twice in one invocation,
//! once served live with a client subscribed to every channel at the loop's
//! rate, once without a live server, both timed by the plant itself, so
//! that the difference is what the live view costs the loop. The server's
//! own CPU time is reported beside it (`live_summary.json`).

use crate::ab_table::Options;
use anyhow::{Context, bail};
use flexloop_live::LiveOptions;
use flexloop_runfiles::bench::LiveCost;
use flexloop_runfiles::json::{read_json, write_json_atomically};
use flexloop_runfiles::live::LiveSummary;
use flexloop_runfiles::{PlantLatency, RunDir};
use flexloop_supervisor::launch::{prepare, resolve_scenario, stamped_run_dir, supervise};
use std::io::ErrorKind;
use std::net::TcpStream;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;
use tungstenite::client::IntoClientRequest;
use tungstenite::http::HeaderValue;
use tungstenite::{Message, WebSocket};

const SUBPROTOCOL: &str = "foxglove.sdk.v1";

/// What the client received.
#[derive(Debug, Default, Clone, Copy)]
struct Received {
    messages: u64,
    bytes: u64,
}

/// One run, served live with a client subscribed to everything when `live`.
fn run_once(
    o: &Options,
    scenario: &Path,
    run_dir: &Path,
    live: bool,
) -> anyhow::Result<(PlantLatency, Received)> {
    let args = o.loop_args(scenario, run_dir);
    let mut prepared = prepare(&args)?;
    if live {
        // Any free port; the bench changes nothing.
        prepared.live = Some(LiveOptions::checked(
            "127.0.0.1:0".parse().expect("an address"),
            false,
            None,
            true,
        )?);
    }
    let stop = Arc::new(AtomicBool::new(false));
    let mut client: Option<JoinHandle<anyhow::Result<Received>>> = None;
    let finished = supervise(prepared, |_, _| {
        if live
            && client.is_none()
            && let Ok(endpoint) = flexloop_live::endpoint(run_dir)
        {
            let stop = Arc::clone(&stop);
            client = Some(std::thread::spawn(move || {
                subscribe_to_everything(&endpoint.address, &stop)
            }));
        }
        None
    });
    stop.store(true, Ordering::Release);
    let received = match client {
        Some(handle) => handle
            .join()
            .map_err(|_| anyhow::anyhow!("the live client panicked"))??,
        None if live => bail!("the live server never listened"),
        None => Received::default(),
    };
    finished?;
    Ok((RunDir::new(run_dir).read_plant_latency()?, received))
}

/// A Foxglove client subscribed to every channel the server advertises,
/// reading as fast as it can until the server goes or `stop` is set.
fn subscribe_to_everything(address: &str, stop: &AtomicBool) -> anyhow::Result<Received> {
    let stream = TcpStream::connect(address).with_context(|| format!("connect to {address}"))?;
    let mut request = format!("ws://{address}").into_client_request()?;
    request.headers_mut().insert(
        "Sec-WebSocket-Protocol",
        HeaderValue::from_static(SUBPROTOCOL),
    );
    let (mut ws, _) =
        tungstenite::client(request, stream).map_err(|e| anyhow::anyhow!("handshake: {e}"))?;
    ws.get_ref()
        .set_read_timeout(Some(Duration::from_millis(100)))?;
    let mut received = Received::default();
    let mut subscriptions = 0u32;
    while !stop.load(Ordering::Acquire) {
        match ws.read() {
            Ok(Message::Text(text)) => subscribe(&mut ws, text.as_str(), &mut subscriptions)?,
            Ok(Message::Binary(data)) => {
                received.messages += 1;
                received.bytes += data.len() as u64;
            }
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
            // The server stopped with the run.
            Err(_) => break,
        }
    }
    Ok(received)
}

/// Subscribes to every channel an `advertise` message names.
fn subscribe(
    ws: &mut WebSocket<TcpStream>,
    text: &str,
    subscriptions: &mut u32,
) -> anyhow::Result<()> {
    let message: serde_json::Value = serde_json::from_str(text)?;
    if message["op"] != "advertise" {
        return Ok(());
    }
    let mut subs = Vec::new();
    for channel in message["channels"].as_array().into_iter().flatten() {
        *subscriptions += 1;
        subs.push(serde_json::json!({"id": *subscriptions, "channelId": channel["id"]}));
    }
    let request = serde_json::json!({"op": "subscribe", "subscriptions": subs});
    ws.send(Message::Text(request.to_string().into()))?;
    Ok(())
}

pub fn live_cost(o: Options) -> anyhow::Result<i32> {
    let scenario = resolve_scenario(o.scenario.clone())?;
    let root = o
        .out
        .clone()
        .unwrap_or_else(|| stamped_run_dir("live-cost"));
    std::fs::create_dir_all(&root).with_context(|| root.display().to_string())?;
    eprintln!(
        "flexloop bench --live-cost: {} for {} s served live with a client subscribed to everything, \
         then {} s without a live server; runs in {}",
        scenario.display(),
        o.duration_s,
        o.duration_s,
        root.display()
    );
    let with_dir = root.join("with-client");
    let (with, received) = run_once(&o, &scenario, &with_dir, true)?;
    if flexloop_runtime::shutdown::requested() {
        bail!("interrupted");
    }
    let (without, _) = run_once(&o, &scenario, &root.join("without-server"), false)?;
    let server: LiveSummary = read_json(&RunDir::new(&with_dir).live_summary())?;

    let cost = crate::ab_table::print(("live client", &with), ("no live server", &without));
    let (p50_cost, p9999_cost) = (cost.p50_us, cost.p9999_us);
    println!(
        "\nthe live view costs {p50_cost:+.1} µs at the round trip's p50 and {p9999_cost:+.1} µs at p99.99"
    );
    println!(
        "the server: {:.1} % of one CPU ({:.2} s CPU in {:.1} s), {} messages sent, {} samples its reader lost; \
         the client received {} messages ({:.1} MB/s)",
        100.0 * server.cpu_s / server.wall_s.max(1e-9),
        server.cpu_s,
        server.wall_s,
        server.messages_sent,
        server.lost_by_reader.iter().sum::<u64>(),
        received.messages,
        received.bytes as f64 / 1e6 / o.duration_s
    );
    println!("{}", crate::ab_table::NOISE_CAVEAT);
    let document = LiveCost {
        scenario: scenario.display().to_string(),
        duration_s: o.duration_s,
        with_client: with,
        without_server: without,
        server,
        client_messages: received.messages,
        client_bytes: received.bytes,
        round_trip_p50_cost_us: p50_cost,
        round_trip_p9999_cost_us: p9999_cost,
    };
    let path = root.join("live_cost.json");
    write_json_atomically(&path, &document)?;
    println!("{}", path.display());
    Ok(0)
}
