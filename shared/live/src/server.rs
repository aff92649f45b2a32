//! The server: Foxglove's WebSocket server (the `foxglove` crate) with the
//! loop's channels, its tunables as parameters, and the reader that feeds
//! it from the loop's channels.
//!
//! The reader is one more polling subscriber of the loop (as the logger
//! is: no notification, so no publisher of the loop ever waits on it). It
//! runs in the process that calls [`serve`], which the supervisor starts
//! off the loop's CPU and priority. What a client cannot take in time is
//! dropped from its own queue (the crate keeps the newest
//! `BACKLOG` messages per client); the loop, the logger and the other
//! clients never wait for it.
//!
//! Clients reach the crate's server (on loopback, a port of the system's
//! choosing) through the [`gate`](crate::gate) on the public address: at
//! most 16 at once, no message over 64 KiB, and each marked, so that the
//! server serves only those (a connection made straight to the crate's port
//! gets the channels' advertisements and nothing else). Of a set, the token
//! is looked at first; nothing else of it is converted or handed on unless
//! the client may change the loop.

use crate::clients::{ClientTable, RATE_PARAMETER, Route, TOKEN_PARAMETER, targets};
use crate::counts::Counts;
pub use crate::error::LiveError;
use crate::feeds::{EventsTail, LatencyFeed, ScenarioWatch};
use crate::gate::{Admissions, Gate, GateCounts, Limits, MARK_PARAMETER, MAX_CLIENTS, Mark};
use crate::measured::MeasureFeed;
use crate::options::LiveOptions;
use crate::parameters;
use crate::reader::LoopReader;
use crate::token::{self, Attempt, Throttle};
use crate::tuning::{SetOutcome, Tuner};
use flexloop_protocol::layout::{self, MessageLayout};
use flexloop_recording::sample_file::{
    COMMAND_TOPIC, ESTIMATE_TOPIC, EVENT_SCHEMA, EVENT_SCHEMA_NAME, EVENTS_TOPIC, MEASUREMENT_TOPIC,
};
use flexloop_runfiles::RunDir;
use flexloop_runfiles::json::write_json_atomically;
use flexloop_runfiles::live::{LiveEndpoint, LiveSummary};
use flexloop_runtime::{monotonic_ns, shutdown};
use flexloop_transport::Domain;
use foxglove::websocket::{
    AnyClient, Capability, ChannelView, Client, ClientId, GetParametersResponder, Parameter,
    ParameterHandler, ParameterValue, ServerListener, SetParametersResponder,
};
use foxglove::{
    ChannelBuilder, Context, PartialMetadata, RawChannel, Schema, SinkId, WebSocketServer,
    WebSocketServerHandle,
};
use std::collections::HashMap;
use std::net::{Ipv4Addr, SocketAddr, TcpListener};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant, SystemTime};

pub const LATENCY_TOPIC: &str = "/latency";
pub const SCENARIO_TOPIC: &str = "/scenario";
pub const RESPONSE_TOPIC: &str = "/measurement/response";

/// Messages queued per client before the oldest are dropped (and, apart,
/// control messages: statuses and parameter answers, a client that lets
/// those fill is disconnected by the crate). A queued sample message costs
/// its bytes and 13 of header, and the three differ: `/measurement` 360,
/// `/command` 456, `/estimate` 4 352 bytes, 5.2 KB for one tick of every
/// channel. 1 024 of them: 34 ms of every channel at
/// 10 kHz, 3.4 s at the 100 Hz a browser would name; a client that never
/// reads holds about 2 MB subscribed to everything, 4.5 MB to `/estimate`
/// alone, so the gate's 16 clients at most 72 MB (8 192, as before: 15 MB
/// each subscribed to everything, 240 MB for 16).
pub const BACKLOG: usize = 1024;
/// The reader's poll: as the logger's, well inside the queues' 51 ms.
const POLL: Duration = Duration::from_millis(2);
const EVENTS_EVERY: Duration = Duration::from_millis(100);

const LATENCY_SCHEMA: &str = r#"{
  "title": "flexloop/Latency",
  "description": "Once a second: the logger's counters and latency percentiles (what `flexloop status` prints) and the live server's own counts",
  "type": "object",
  "properties": {
    "seq": {"type": "integer", "description": "the loop's newest tick"},
    "rate_hz": {"type": "number", "description": "samples per second since the last message"},
    "samples": {"type": "integer"},
    "misses": {"type": "integer"},
    "late_commands": {"type": "integer"},
    "stalled_ticks": {"type": "integer"},
    "stall_misses": {"type": "integer"},
    "stale_estimates": {"type": "integer"},
    "log_gaps": {"type": "integer"},
    "round_trip_us": {"type": "object", "description": "p50, p90, p99, p99.9, p99.99, max"},
    "tick_lateness_us": {"type": "object"},
    "live": {"type": "object", "description": "clients subscribed, connections open and refused (beyond the 16 served), messages sent, samples the live reader lost per channel; you.handed: the messages the server handed to this client before this one (less those it received: what its queue dropped)"}
  }
}"#;

const SCENARIO_SCHEMA: &str = r#"{
  "title": "flexloop/Scenario",
  "description": "The loop's scenario as it stands (after swaps and sets): on subscribing, and again whenever it changes",
  "type": "object",
  "properties": {
    "file": {"type": "string"},
    "toml": {"type": "string"}
  }
}"#;

const RESPONSE_SCHEMA: &str = r#"{
  "title": "flexloop/MeasuredResponse",
  "description": "A measurement's frequency responses while it runs (docs/control.md §14): after each measured period (a stepped sine: each tone), the responses over the periods so far, as `flexloop measure` computes them; a stopped live estimate says why. Plot an array of `responses` against `frequencies_hz` (Plot panel, x axis: path (current))",
  "type": "object",
  "properties": {
    "measurement": {"type": "string", "description": "`scenario` (its [measure]) or `at-<start tick>` (ordered on the running loop): the label `flexloop measure` gives it"},
    "state": {"type": "string", "enum": ["measuring", "done", "stopped", "failed", "unavailable"], "description": "stopped: the server missed samples of a period (or its start), the estimate of the periods before stands; failed: the measurement cannot be computed; unavailable: not estimated live (why in note)"},
    "note": {"type": "string", "description": "why it stopped, failed or is unavailable, and that `flexloop measure RUN_DIR` computes it from the recording"},
    "missed_samples": {"type": "integer", "description": "with state stopped: the samples of the period (or before the start) the server did not see"},
    "start_tick": {"type": ["integer", "null"], "description": "the first tick the excitation ran (EXCITING)"},
    "planned_start_tick": {"type": "integer"},
    "point": {"type": "string", "description": "where the excitation enters (plant-input, sensor, ...)"},
    "signal": {"type": "string", "description": "multisine, swept-sine or stepped-sine"},
    "period_samples": {"type": "integer"},
    "transient_periods": {"type": "integer"},
    "periods_done": {"type": "integer", "description": "measured periods the estimate averages (a stepped sine: of all its tones so far)"},
    "periods_total": {"type": "integer"},
    "frequencies_hz": {"type": "array", "items": {"type": "number"}, "description": "the lines estimated so far"},
    "log10_frequencies_hz": {"type": "array", "items": {"type": "number"}, "description": "the same, log10: a logarithmic frequency axis for a plot without one"},
    "responses": {"type": "object", "description": "per response, named as `flexloop measure` names them (P, S_i, T_i, PS, L_i at the plant input; P, S_o, T_o, CS, L_o at the sensor): meaning, magnitude_db, phase_deg, coherence at each line, and where the design predicts it model_magnitude_db, model_phase_deg"},
    "periods_used": {"type": "integer"},
    "periods_saturated": {"type": "array", "items": {"type": "integer"}, "description": "measured periods left out: the actuator reached its limit in them"},
    "sensitivity": {"type": "object", "description": "the measured sensitivity's peak over the lines of coherence >= min_coherence (peak_db, peak_hz), whether it keeps the 6 dB rule (keeps_6db_rule, limit_db), and the design's peak over the same lines (model_peak_db, model_peak_hz)"}
  }
}"#;

/// The running loop the server serves.
#[derive(Debug, Clone)]
pub struct LoopSide {
    pub prefix: String,
    pub run_dir: PathBuf,
    pub rate_hz: f64,
}

/// What the server's callbacks share with the reader.
struct Shared {
    table: Mutex<ClientTable<ClientId, SinkId>>,
    /// The gate's open connections, and the client each turned out to be
    /// once its mark arrived.
    connections: Mutex<HashMap<u64, Option<ClientId>>>,
    mark: Arc<Mark>,
    throttle: Mutex<Throttle>,
    /// Clients that subscribed to `/scenario` and wait for it.
    scenario_wanted: Mutex<Vec<SinkId>>,
    scenario_topic_id: Mutex<Option<u64>>,
    /// Clients that subscribed to `/measurement/response` and wait for
    /// its latest message.
    response_wanted: Mutex<Vec<SinkId>>,
    response_topic_id: u64,
    options: LiveOptions,
    tuner: Arc<dyn Tuner>,
    server: Mutex<Option<WebSocketServerHandle>>,
    /// One change of the loop at a time: another is refused meanwhile.
    setting: AtomicBool,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // The state stays consistent across a panicking callback (each update
    // is one call), so a poisoned lock is still usable.
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Told to a client that did not come through the gate.
const NOT_ADMITTED: &str = "not a client of this server: connect to the address in live.json";

struct Listener(Arc<Shared>);

impl ServerListener for Listener {
    fn on_subscribe(&self, client: Client, channel: ChannelView) {
        let Some(sink) = client.sink_id() else {
            return;
        };
        let id = u64::from(channel.id());
        if !lock(&self.0.table).subscribed(client.id(), sink, id) {
            return;
        }
        if *lock(&self.0.scenario_topic_id) == Some(id) {
            lock(&self.0.scenario_wanted).push(sink);
        }
        if self.0.response_topic_id == id {
            lock(&self.0.response_wanted).push(sink);
        }
    }

    fn on_unsubscribe(&self, client: Client, channel: ChannelView) {
        lock(&self.0.table).unsubscribed(client.id(), u64::from(channel.id()));
    }
}

/// The gate's connections, told to the server.
struct Doorman(Arc<Shared>);

impl Admissions for Doorman {
    fn opened(&self, n: u64) {
        lock(&self.0.connections).insert(n, None);
    }

    fn closed(&self, n: u64) {
        if let Some(Some(client)) = lock(&self.0.connections).remove(&n) {
            lock(&self.0.table).forget(client);
        }
    }
}

struct Parameters(Arc<Shared>);

impl Shared {
    /// The gate's mark (the first message of a connection through it):
    /// `client` is the connection it names, if that is open and not yet
    /// claimed and the secret is the gate's.
    fn admit(&self, client: ClientId, value: Option<&ParameterValue>) {
        let Some(ParameterValue::String(value)) = value else {
            return;
        };
        let Some(n) = self.mark.connection(value) else {
            return;
        };
        let mut connections = lock(&self.connections);
        if let Some(slot) = connections.get_mut(&n)
            && slot.is_none()
        {
            *slot = Some(client);
            lock(&self.table).admit(client);
        }
    }

    fn admitted(&self, client: ClientId) -> bool {
        lock(&self.table).admitted(client)
    }

    /// Every parameter this client sees: the loop's tunables (when
    /// `tunables`) and its own rate.
    fn parameters(&self, client: ClientId, tunables: bool) -> (Vec<Parameter>, Option<String>) {
        let (mut out, error) = match tunables.then(|| self.tuner.values()) {
            None => (Vec::new(), None),
            Some(Ok(values)) => (
                values
                    .iter()
                    .map(|(field, value)| parameters::parameter(field, value.as_ref()))
                    .collect(),
                None,
            ),
            Some(Err(reason)) => (Vec::new(), Some(reason)),
        };
        out.push(Parameter {
            name: RATE_PARAMETER.to_string(),
            r#type: None,
            value: Some(ParameterValue::Float64(lock(&self.table).rate_hz(client))),
        });
        (out, error)
    }

    /// The token of a set request, looked at before anything else of it:
    /// compared in constant time unless wrong ones lock attempts out; a
    /// wrong one logged.
    fn take_token(&self, client: &AnyClient, value: Option<&ParameterValue>) {
        let Some(token) = &self.options.token else {
            client.send_warning(format!("{TOKEN_PARAMETER}: this server takes no token"));
            return;
        };
        let given = match value {
            Some(ParameterValue::String(given)) => given.as_bytes(),
            _ => &[],
        };
        let attempt = lock(&self.throttle).attempt(Instant::now(), || token::matches(token, given));
        match attempt {
            Attempt::Accepted => lock(&self.table).give_token(client.id()),
            Attempt::Wrong { failures, lockout } => {
                let then = if lockout.is_zero() {
                    String::new()
                } else {
                    format!(
                        "; every token is refused unexamined for {} s",
                        lockout.as_secs()
                    )
                };
                eprintln!(
                    "flexloop-live: a wrong {TOKEN_PARAMETER} ({failures} wrong so far{then})"
                );
                client.send_error(format!("{TOKEN_PARAMETER}: not the server's token{then}"));
            }
            Attempt::Throttled { left } => client.send_error(format!(
                "{TOKEN_PARAMETER}: too many wrong tokens; none is examined for another {:.1} s",
                left.as_secs_f64()
            )),
        }
    }

    /// A set request of `client`: its token first, then its own rate, then
    /// the loop's fields, converted only if the client may change the loop
    /// (read-only or without the token: refused unlooked-at). The changes
    /// of the loop it asks for, as `flexloop set` takes them.
    fn screen(&self, client: &AnyClient, requested: &[Parameter]) -> Vec<(String, String)> {
        let id = client.id();
        for p in requested.iter().filter(|p| p.name == TOKEN_PARAMETER) {
            self.take_token(client, p.value.as_ref());
        }
        let may_change = if self.options.read_only {
            Err("this live server is read-only (--live-read-only)".to_string())
        } else if self.options.token.is_some() && !lock(&self.table).token_given(id) {
            Err(format!(
                "set {TOKEN_PARAMETER} to the token the server was started with first"
            ))
        } else {
            Ok(())
        };
        let mut changes = Vec::new();
        let mut refused = false;
        for p in requested {
            match p.name.as_str() {
                TOKEN_PARAMETER => {}
                RATE_PARAMETER => {
                    let named = parameters::number(&p.name, p.value.as_ref())
                        .and_then(|rate| lock(&self.table).set_rate(id, rate));
                    if let Err(reason) = named {
                        client.send_error(reason);
                    }
                }
                MARK_PARAMETER => {
                    client.send_error(format!("{MARK_PARAMETER}: not a parameter one sets"));
                }
                field if may_change.is_ok() => {
                    match parameters::toml_text(field, p.value.as_ref()) {
                        Ok(text) => changes.push((field.to_string(), text)),
                        Err(reason) => client.send_error(format!("set refused: {reason}")),
                    }
                }
                _ => refused = true,
            }
        }
        if let (true, Err(reason)) = (refused, may_change) {
            client.send_error(format!("set refused: {reason}"));
        }
        changes
    }

    /// Changes the loop (on a thread of its own: a change takes as long as
    /// its hand-over), and tells every client of the new values.
    fn change(&self, client: &AnyClient, changes: &[(String, String)]) {
        match self.change_loop(client.id(), changes) {
            Ok(outcome) => {
                client.send_info(outcome.summary.clone());
                if let Some(server) = lock(&self.server).as_ref() {
                    let (all, _) = self.parameters(client.id(), true);
                    let changed = all
                        .into_iter()
                        .filter(|p| outcome.fields.contains(&p.name))
                        .collect::<Vec<_>>();
                    if !changed.is_empty() {
                        server.publish_parameter_values(changed);
                    }
                }
            }
            Err(reason) => client.send_error(format!("set refused: {reason}")),
        }
    }

    /// The answer to a set: the values of the parameters it named as they
    /// now stand (the loop's tunables asked of the loop only if it named
    /// any).
    fn answer(&self, client: ClientId, names: &[String]) -> Vec<Parameter> {
        let own = [TOKEN_PARAMETER, RATE_PARAMETER, MARK_PARAMETER];
        let tunables = names.iter().any(|n| !own.contains(&n.as_str()));
        let (all, _) = self.parameters(client, tunables);
        all.into_iter()
            .filter(|p| names.contains(&p.name))
            .collect()
    }

    fn change_loop(
        &self,
        client: ClientId,
        changes: &[(String, String)],
    ) -> Result<SetOutcome, String> {
        if self.options.read_only {
            return Err("this live server is read-only (--live-read-only)".into());
        }
        if self.options.token.is_some() && !lock(&self.table).token_given(client) {
            return Err(format!(
                "set {TOKEN_PARAMETER} to the token the server was started with first"
            ));
        }
        if self.setting.swap(true, Ordering::AcqRel) {
            return Err("another change is being handed over; set again when it is done".into());
        }
        let outcome = self.tuner.set(changes);
        self.setting.store(false, Ordering::Release);
        outcome
    }
}

impl ParameterHandler for Parameters {
    fn get(
        &self,
        client: AnyClient,
        names: Vec<String>,
        _request_id: Option<String>,
        responder: GetParametersResponder,
    ) {
        if !self.0.admitted(client.id()) {
            client.send_error(NOT_ADMITTED);
            responder.respond(Vec::new());
            return;
        }
        let (all, error) = self.0.parameters(client.id(), true);
        if let Some(reason) = error {
            client.send_error(reason);
        }
        responder.respond(
            all.into_iter()
                .filter(|p| names.is_empty() || names.contains(&p.name))
                .collect(),
        );
    }

    fn set(
        &self,
        client: AnyClient,
        parameters: Vec<Parameter>,
        _request_id: Option<String>,
        responder: SetParametersResponder,
    ) {
        let shared = &self.0;
        if let [only] = parameters.as_slice()
            && only.name == MARK_PARAMETER
        {
            shared.admit(client.id(), only.value.as_ref());
            responder.respond(Vec::new());
            return;
        }
        if !shared.admitted(client.id()) {
            client.send_error(NOT_ADMITTED);
            responder.respond(Vec::new());
            return;
        }
        let changes = shared.screen(&client, &parameters);
        let names: Vec<String> = parameters.into_iter().map(|p| p.name).collect();
        if changes.is_empty() {
            responder.respond(shared.answer(client.id(), &names));
            return;
        }
        let shared = Arc::clone(shared);
        let spawned = std::thread::Builder::new()
            .name("live-set".into())
            .spawn(move || {
                shared.change(&client, &changes);
                responder.respond(shared.answer(client.id(), &names));
            });
        if let Err(e) = spawned {
            // The responder went with the closure: the crate answers the
            // client with an internal error.
            eprintln!("flexloop-live: cannot handle a set: {e}");
        }
    }
}

/// The Foxglove channels of the loop's messages.
struct Channels {
    samples: [Arc<RawChannel>; 3],
    events: Arc<RawChannel>,
    latency: Arc<RawChannel>,
    scenario: Arc<RawChannel>,
    response: Arc<RawChannel>,
}

impl Channels {
    fn new(ctx: &Arc<Context>) -> Result<Self, LiveError> {
        let ros1 = |topic: &'static str, layout: &MessageLayout| {
            ChannelBuilder::new(topic)
                .context(ctx)
                .message_encoding("ros1")
                .schema(Schema::new(
                    layout.type_name,
                    "ros1msg",
                    layout.ros1_definition().into_bytes(),
                ))
                .build_raw()
                .map_err(|e| LiveError::Channel {
                    topic,
                    reason: e.to_string(),
                })
        };
        let json = |topic: &'static str, name: &str, schema: &'static str| {
            ChannelBuilder::new(topic)
                .context(ctx)
                .message_encoding("json")
                .schema(Schema::new(name, "jsonschema", schema.as_bytes()))
                .build_raw()
                .map_err(|e| LiveError::Channel {
                    topic,
                    reason: e.to_string(),
                })
        };
        Ok(Self {
            samples: [
                ros1(MEASUREMENT_TOPIC, &layout::MEASUREMENT)?,
                ros1(ESTIMATE_TOPIC, &layout::ESTIMATE)?,
                ros1(COMMAND_TOPIC, &layout::COMMAND)?,
            ],
            events: json(EVENTS_TOPIC, EVENT_SCHEMA_NAME, EVENT_SCHEMA)?,
            latency: json(LATENCY_TOPIC, "flexloop/Latency", LATENCY_SCHEMA)?,
            scenario: json(SCENARIO_TOPIC, "flexloop/Scenario", SCENARIO_SCHEMA)?,
            response: json(RESPONSE_TOPIC, "flexloop/MeasuredResponse", RESPONSE_SCHEMA)?,
        })
    }
}

/// Serves the loop until a stop is requested (SIGTERM or SIGINT; the
/// supervisor sends it at the end of the run). Writes `live.json` in the
/// run directory once it listens.
pub fn serve(
    options: LiveOptions,
    side: &LoopSide,
    tuner: Arc<dyn Tuner>,
) -> Result<(), LiveError> {
    let address = options.address;
    let start_error = |reason: String| LiveError::Start {
        address: address.to_string(),
        reason,
    };
    let mark = Arc::new(Mark::new().map_err(|e| start_error(format!("no random secret: {e}")))?);
    let listener = TcpListener::bind(address).map_err(|e| start_error(e.to_string()))?;
    let ctx = Context::new();
    let channels = Channels::new(&ctx)?;
    let shared = Arc::new(Shared {
        table: Mutex::new(ClientTable::new(side.rate_hz)),
        connections: Mutex::new(HashMap::new()),
        mark: Arc::clone(&mark),
        throttle: Mutex::new(Throttle::default()),
        scenario_wanted: Mutex::new(Vec::new()),
        scenario_topic_id: Mutex::new(Some(u64::from(channels.scenario.id()))),
        response_wanted: Mutex::new(Vec::new()),
        response_topic_id: u64::from(channels.response.id()),
        options: options.clone(),
        tuner,
        server: Mutex::new(None),
        setting: AtomicBool::new(false),
    });
    // The crate's server, on loopback: clients reach it through the gate.
    let handle = WebSocketServer::new()
        .context(&ctx)
        .name(format!("flexloop {}", side.prefix))
        .bind(Ipv4Addr::LOCALHOST.to_string(), 0)
        .capabilities([Capability::Parameters])
        .message_backlog_size(BACKLOG)
        .listener(Arc::new(Listener(Arc::clone(&shared))))
        .parameter_handler(Arc::new(Parameters(Arc::clone(&shared))))
        .start_blocking()
        .map_err(|e| start_error(e.to_string()))?;
    let inner = SocketAddr::new(Ipv4Addr::LOCALHOST.into(), handle.port());
    *lock(&shared.server) = Some(handle);
    let mut gate = Gate::start(
        listener,
        inner,
        Limits::default(),
        mark,
        Arc::new(Doorman(Arc::clone(&shared))),
    )
    .map_err(|e| start_error(e.to_string()))?;
    let run_dir = RunDir::new(&side.run_dir);
    write_json_atomically(
        &run_dir.live(),
        &LiveEndpoint {
            address: gate.address().to_string(),
            pid: std::process::id(),
            read_only: options.read_only,
            token_required: options.token.is_some(),
        },
    )
    .map_err(LiveError::RunFile)?;
    let started = std::time::Instant::now();
    let mut counts = Counts::default();
    let result = feed(side, &channels, &shared, gate.counts(), &mut counts);
    gate.stop();
    if let Some(handle) = lock(&shared.server).take() {
        // Dropping the shutdown handle closes every connection now: a
        // client that never reads must not hold up the end of the run.
        drop(handle.stop());
    }
    let (token_failures, token_throttled) = {
        let throttle = lock(&shared.throttle);
        (throttle.failures(), throttle.throttled())
    };
    if token_throttled > 0 {
        eprintln!(
            "flexloop-live: {token_throttled} {TOKEN_PARAMETER} attempt(s) refused unexamined \
             after wrong ones ({token_failures} wrong tokens compared)"
        );
    }
    let gate_counts = gate.counts();
    write_json_atomically(
        &run_dir.live_summary(),
        &LiveSummary {
            cpu_s: flexloop_runtime::usage::process_cpu_ns() as f64 / 1e9,
            wall_s: started.elapsed().as_secs_f64(),
            messages_sent: counts.sent(),
            lost_by_reader: counts.lost,
            most_clients: counts.most_clients,
            max_connections: MAX_CLIENTS,
            most_connections: gate_counts.most_connected(),
            refused_connections: gate_counts.refused(),
            oversized_messages: gate_counts.oversized(),
            token_failures,
            token_throttled,
        },
    )
    .map_err(LiveError::RunFile)?;
    result
}

/// Reads the loop's channels and hands every message to the clients that
/// want it, until a stop is requested.
fn feed(
    side: &LoopSide,
    channels: &Channels,
    shared: &Shared,
    gate: &GateCounts,
    counts: &mut Counts,
) -> Result<(), LiveError> {
    let domain = Domain::new(&side.prefix)?;
    let node = domain.node("live")?;
    let mut reader = LoopReader::open(&node)?;
    let mut events = EventsTail::new(RunDir::new(&side.run_dir).events());
    let mut scenario = ScenarioWatch::default();
    let mut latency = LatencyFeed::open(&node)?;
    // Planned, designed and estimated on threads of its own: this loop
    // only copies the samples of a measurement's periods.
    let mut measuring = MeasureFeed::start(&side.run_dir, side.rate_hz);
    let mut latest_response: Option<String> = None;
    let offset_ns = wall_clock_ns().saturating_sub(monotonic_ns());
    let ids = channels.samples.each_ref().map(|c| u64::from(c.id()));
    let mut routes: Vec<Route<SinkId>> = Vec::new();
    let mut routes_version = u64::MAX;
    let mut out = Vec::new();
    let mut next_events = std::time::Instant::now();
    while !shutdown::requested() {
        {
            let table = lock(&shared.table);
            if table.version() != routes_version {
                table.routes(&mut routes);
                routes_version = table.version();
                counts.most_clients = counts.most_clients.max(table.subscribed_clients());
                counts.forget_gone(&routes);
            }
        }
        reader.drain(
            &mut |k, seq, published_ns, bytes| {
                counts.read(k, seq);
                targets(&routes, ids[k], seq, &mut out);
                for sink in &out {
                    channels.samples[k].log_with_meta_to_sink(
                        bytes,
                        PartialMetadata {
                            log_time: Some(published_ns.wrapping_add(offset_ns)),
                        },
                        Some(*sink),
                    );
                    counts.handed(*sink);
                }
            },
            &mut |m| measuring.sample(m),
        )?;
        measuring.poll(&mut |json| {
            counts.log_to_subscribers(&channels.response, &routes, json.as_bytes());
            latest_response = Some(json);
        });
        if let Some(mut json) = latency.poll(counts, routes.len(), gate)? {
            // Each client's own copy says how many messages the server
            // handed to it before this one: what it received less that is
            // what its queue dropped.
            let latency_id = u64::from(channels.latency.id());
            for route in routes.iter().filter(|r| r.channels.contains(&latency_id)) {
                json["live"]["you"] = serde_json::json!({"handed": counts.handed_to(route.sink)});
                channels
                    .latency
                    .log_to_sink(json.to_string().as_bytes(), Some(route.sink));
                counts.handed(route.sink);
            }
        }
        if std::time::Instant::now() >= next_events {
            next_events += EVENTS_EVERY;
            for line in events.new_lines() {
                counts.log_to_subscribers(&channels.events, &routes, line.as_bytes());
                measuring.event(&line);
            }
            // A client that subscribes while a measurement runs (or after)
            // gets its latest message at once.
            let wanted: Vec<SinkId> = std::mem::take(&mut *lock(&shared.response_wanted));
            if let Some(json) = &latest_response {
                for sink in wanted {
                    channels.response.log_to_sink(json.as_bytes(), Some(sink));
                    counts.handed(sink);
                }
            }
            let wanted: Vec<SinkId> = std::mem::take(&mut *lock(&shared.scenario_wanted));
            if let Some(json) = scenario.changed(&shared.tuner) {
                counts.log_to_subscribers(&channels.scenario, &routes, json.as_bytes());
            } else if !wanted.is_empty()
                && let Some(json) = scenario.current(&shared.tuner)
            {
                for sink in wanted {
                    channels.scenario.log_to_sink(json.as_bytes(), Some(sink));
                    counts.handed(sink);
                }
            }
        }
        std::thread::sleep(POLL);
    }
    Ok(())
}

fn wall_clock_ns() -> u64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// Where `serve` says it listens.
pub fn endpoint(run_dir: &Path) -> Result<LiveEndpoint, flexloop_runfiles::FileError> {
    flexloop_runfiles::json::read_json(&RunDir::new(run_dir).live())
}
