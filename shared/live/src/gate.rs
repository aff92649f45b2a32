//! The gate: the live server's public address, in front of the `foxglove`
//! crate's WebSocket server, which listens on loopback on a port of the
//! system's choosing. The crate takes every connection, and every message
//! up to tungstenite's defaults (16 MiB frames, 64 MiB messages, parsed
//! whole before the server sees them), with no setting for either. The
//! gate:
//!
//! - admits at most [`MAX_CLIENTS`] connections at once; one beyond is
//!   answered `503 Service Unavailable` at once and closed, counted and
//!   logged (what it costs: a socket for a moment);
//! - reads the client's HTTP request head (at most 8 KiB, within 10 s), then
//!   follows the headers of the WebSocket frames the client sends: a frame,
//!   or a message of several frames, longer than [`MAX_MESSAGE_BYTES`]
//!   closes the connection before its first payload byte reaches the crate,
//!   counted and logged;
//! - marks each connection it passes on: its first message to the crate is
//!   a `setParameters` of [`MARK_PARAMETER`] to `SECRET:N` (a random secret
//!   of this process, N the connection's number), so that the server serves
//!   only connections that came through the gate (not one made straight to
//!   the crate's port) and forgets each client when its connection ends.
//!
//! What the crate sends goes back unchanged through a 16 KiB buffer, with
//! the sockets' kernel buffers on the gate's side fixed at 256 KiB: a
//! client that does not read holds the crate's queue for it (its
//! `message_backlog_size`) and those buffers, nothing more.

use std::io::{self, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::os::fd::AsRawFd;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Connections served at once. A Foxglove or PlotJuggler window is one; a
/// client that never reads costs the server its queue (1 024 messages, at
/// most 4.5 MB: `server::BACKLOG`), so this bounds what slow clients can
/// take to 16 such queues.
pub const MAX_CLIENTS: usize = 16;
/// The longest message (all its frames) a client may send. The largest a
/// client has reason to send, a `setParameters` of every tunable or a
/// subscription to every channel, is well under 4 KiB; the crate parses a
/// message whole before the server sees it, so this bounds what one costs.
pub const MAX_MESSAGE_BYTES: u64 = 64 * 1024;
/// The parameter the gate marks a connection with.
pub const MARK_PARAMETER: &str = "live.gate";

const MAX_REQUEST_HEAD: usize = 8 * 1024;
const HANDSHAKE_LIMIT: Duration = Duration::from_secs(10);
const CONNECT_LIMIT: Duration = Duration::from_secs(5);
const BUFFER: usize = 16 * 1024;
/// The gate's side of each connection's sockets (the kernel doubles it).
const SOCKET_BUFFER: libc::c_int = 128 * 1024;
const THREAD_STACK: usize = 256 * 1024;
/// A refusal or a closed connection is logged at most this often (with the
/// count since the last line); every one is counted.
const LOG_EVERY: Duration = Duration::from_secs(10);

/// What the gate tells the server of its connections.
pub trait Admissions: Send + Sync + 'static {
    /// Connection `n` is admitted (before its mark reaches the crate).
    fn opened(&self, n: u64);
    /// Connection `n` has ended (both ways).
    fn closed(&self, n: u64);
}

/// The gate's counts.
#[derive(Debug, Default)]
pub struct GateCounts {
    connected: AtomicUsize,
    most_connected: AtomicUsize,
    refused: AtomicU64,
    oversized: AtomicU64,
}

impl GateCounts {
    /// Connections open now.
    pub fn connected(&self) -> usize {
        self.connected.load(Ordering::Relaxed)
    }

    /// The most connections open at once.
    pub fn most_connected(&self) -> usize {
        self.most_connected.load(Ordering::Relaxed)
    }

    /// Connections refused because [`MAX_CLIENTS`] were open.
    pub fn refused(&self) -> u64 {
        self.refused.load(Ordering::Relaxed)
    }

    /// Connections closed for a message longer than [`MAX_MESSAGE_BYTES`].
    pub fn oversized(&self) -> u64 {
        self.oversized.load(Ordering::Relaxed)
    }
}

/// What the gate lets through.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    pub max_clients: usize,
    pub max_message: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_clients: MAX_CLIENTS,
            max_message: MAX_MESSAGE_BYTES,
        }
    }
}

/// The mark of this process's gate: a random secret.
#[derive(Debug)]
pub struct Mark {
    secret: String,
}

impl Mark {
    /// A new secret, from the system's random source.
    pub fn new() -> io::Result<Self> {
        let mut bytes = [0u8; 16];
        std::fs::File::open("/dev/urandom")?.read_exact(&mut bytes)?;
        Ok(Self {
            secret: bytes.iter().map(|b| format!("{b:02x}")).collect(),
        })
    }

    /// The WebSocket frame (a client's: masked) of the mark of connection `n`.
    fn frame(&self, n: u64) -> Vec<u8> {
        let json = format!(
            r#"{{"op":"setParameters","parameters":[{{"name":"{MARK_PARAMETER}","value":"{}:{n}"}}]}}"#,
            self.secret
        );
        masked_text_frame(json.as_bytes())
    }

    /// The connection a mark's value names, if it is this gate's (the
    /// secret compared in constant time).
    pub fn connection(&self, value: &str) -> Option<u64> {
        let (secret, n) = value.rsplit_once(':')?;
        crate::token::matches(&self.secret, secret.as_bytes())
            .then(|| n.parse().ok())
            .flatten()
    }
}

/// A client's text frame: masked with the key 0, which leaves the payload
/// as it is.
fn masked_text_frame(payload: &[u8]) -> Vec<u8> {
    let mut frame = vec![0x81];
    let n = payload.len();
    if n < 126 {
        frame.push(0x80 | n as u8);
    } else if let Ok(n) = u16::try_from(n) {
        frame.push(0x80 | 126);
        frame.extend(n.to_be_bytes());
    } else {
        frame.push(0x80 | 127);
        frame.extend((n as u64).to_be_bytes());
    }
    frame.extend([0, 0, 0, 0]);
    frame.extend(payload);
    frame
}

/// Follows the WebSocket frames a client sends by their headers, without
/// keeping their payloads: each frame's length, and each message's (its
/// fragments together), within the limit.
#[derive(Debug)]
pub struct FrameFilter {
    max_message: u64,
    header: [u8; 14],
    have: usize,
    payload_left: u64,
    /// The data message under way: its frames' lengths so far.
    message: u64,
}

impl FrameFilter {
    pub fn new(max_message: u64) -> Self {
        Self {
            max_message,
            header: [0; 14],
            have: 0,
            payload_left: 0,
            message: 0,
        }
    }

    /// Follows `bytes`, the next the client sent: `Err(length)`, the
    /// frame's or message's, once one is longer than the limit (nothing of
    /// `bytes` may then go on).
    pub fn pass(&mut self, mut bytes: &[u8]) -> Result<(), u64> {
        while !bytes.is_empty() {
            if self.payload_left > 0 {
                let n = self.payload_left.min(bytes.len() as u64);
                self.payload_left -= n;
                bytes = &bytes[n as usize..];
                continue;
            }
            self.header[self.have] = bytes[0];
            self.have += 1;
            bytes = &bytes[1..];
            if let Some(length) = self.header_length() {
                self.have = 0;
                self.frame(length)?;
            }
        }
        Ok(())
    }

    /// The payload length, once the header is complete.
    fn header_length(&self) -> Option<u64> {
        if self.have < 2 {
            return None;
        }
        let short = self.header[1] & 0x7f;
        let extended = match short {
            126 => 2,
            127 => 8,
            _ => 0,
        };
        let mask = if self.header[1] & 0x80 != 0 { 4 } else { 0 };
        if self.have < 2 + extended + mask {
            return None;
        }
        Some(match extended {
            0 => u64::from(short),
            2 => u64::from(u16::from_be_bytes([self.header[2], self.header[3]])),
            _ => u64::from_be_bytes(self.header[2..10].try_into().expect("8 bytes")),
        })
    }

    fn frame(&mut self, length: u64) -> Result<(), u64> {
        let counted = match self.header[0] & 0x0f {
            // A continuation adds to the message under way.
            0 => {
                self.message = self.message.saturating_add(length);
                self.message
            }
            // Control frames (close, ping, pong) stand alone, within 125 bytes.
            8.. if length > 125 => return Err(length),
            8.. => length,
            // Text, binary (and the reserved ones) start a message.
            _ => {
                self.message = length;
                length
            }
        };
        if counted > self.max_message {
            return Err(counted);
        }
        self.payload_left = length;
        Ok(())
    }
}

/// At most one line every [`LOG_EVERY`], saying how many happened since.
#[derive(Debug, Default)]
struct LogLimit {
    last: Option<Instant>,
    unsaid: u64,
}

impl LogLimit {
    /// One more; `Some(count)` when a line is due (the count includes this one).
    fn note(&mut self, now: Instant) -> Option<u64> {
        self.unsaid += 1;
        if self.last.is_some_and(|l| now.duration_since(l) < LOG_EVERY) {
            return None;
        }
        self.last = Some(now);
        Some(std::mem::take(&mut self.unsaid))
    }
}

struct Context {
    inner: SocketAddr,
    limits: Limits,
    mark: Arc<Mark>,
    admissions: Arc<dyn Admissions>,
    counts: Arc<GateCounts>,
    refused_log: Mutex<LogLimit>,
    oversized_log: Mutex<LogLimit>,
}

/// The gate, accepting on its own thread until stopped.
pub struct Gate {
    address: SocketAddr,
    stopping: Arc<AtomicBool>,
    counts: Arc<GateCounts>,
    accepting: Option<JoinHandle<()>>,
}

impl Gate {
    /// Accepts on `listener` and passes connections on to `inner`.
    pub fn start(
        listener: TcpListener,
        inner: SocketAddr,
        limits: Limits,
        mark: Arc<Mark>,
        admissions: Arc<dyn Admissions>,
    ) -> io::Result<Self> {
        let address = listener.local_addr()?;
        let stopping = Arc::new(AtomicBool::new(false));
        let counts = Arc::new(GateCounts::default());
        let context = Arc::new(Context {
            inner,
            limits,
            mark,
            admissions,
            counts: Arc::clone(&counts),
            refused_log: Mutex::default(),
            oversized_log: Mutex::default(),
        });
        let stop = Arc::clone(&stopping);
        let accepting = std::thread::Builder::new()
            .name("live-gate".into())
            .stack_size(THREAD_STACK)
            .spawn(move || accept(&listener, &context, &stop))?;
        Ok(Self {
            address,
            stopping,
            counts,
            accepting: Some(accepting),
        })
    }

    /// Where it listens.
    pub fn address(&self) -> SocketAddr {
        self.address
    }

    pub fn counts(&self) -> &Arc<GateCounts> {
        &self.counts
    }

    /// Stops accepting and closes its port (open connections end when the
    /// crate's server closes them).
    pub fn stop(&mut self) {
        let Some(accepting) = self.accepting.take() else {
            return;
        };
        self.stopping.store(true, Ordering::Release);
        // Wakes the accepting thread (an unspecified address: to loopback).
        let mut wake = self.address;
        if wake.ip().is_unspecified() {
            wake.set_ip(match wake {
                SocketAddr::V4(_) => std::net::Ipv4Addr::LOCALHOST.into(),
                SocketAddr::V6(_) => std::net::Ipv6Addr::LOCALHOST.into(),
            });
        }
        drop(TcpStream::connect_timeout(&wake, CONNECT_LIMIT));
        let _ = accepting.join();
    }
}

impl Drop for Gate {
    fn drop(&mut self) {
        self.stop();
    }
}

fn accept(listener: &TcpListener, context: &Arc<Context>, stopping: &AtomicBool) {
    let mut next = 0u64;
    loop {
        let accepted = listener.accept();
        if stopping.load(Ordering::Acquire) {
            return;
        }
        let (client, peer) = match accepted {
            Ok(accepted) => accepted,
            Err(_) => {
                // Out of descriptors or a connection reset before it was
                // taken: the next may do.
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
        };
        let counts = &context.counts;
        let max = context.limits.max_clients;
        if counts.connected.load(Ordering::Acquire) >= max {
            counts.refused.fetch_add(1, Ordering::Relaxed);
            refuse(client, max);
            let said = lock(&context.refused_log).note(Instant::now());
            if let Some(count) = said {
                eprintln!(
                    "flexloop-live: refused {count} connection(s) (the last from {peer}): \
                     {max} clients are connected, the most this server serves \
                     ({} refused in all)",
                    counts.refused()
                );
            }
            continue;
        }
        next += 1;
        let n = next;
        let now = counts.connected.fetch_add(1, Ordering::AcqRel) + 1;
        counts.most_connected.fetch_max(now, Ordering::Relaxed);
        context.admissions.opened(n);
        let open = Open {
            context: Arc::clone(context),
            n,
        };
        let spawned = std::thread::Builder::new()
            .name("live-gate-in".into())
            .stack_size(THREAD_STACK)
            .spawn(move || open.relay(client, peer));
        if let Err(e) = spawned {
            eprintln!("flexloop-live: cannot serve a connection from {peer}: {e}");
        }
    }
}

/// Answers a connection beyond the cap and closes it, without waiting on it.
fn refuse(mut client: TcpStream, max: usize) {
    let body =
        format!("the flexloop live server serves at most {max} clients at once; try again later\n");
    let response = format!(
        "HTTP/1.1 503 Service Unavailable\r\nConnection: close\r\n\
         Content-Type: text/plain\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    );
    let _ = client.set_nonblocking(true);
    let _ = client.write(response.as_bytes());
    let _ = client.shutdown(Shutdown::Write);
    // What has come already, so that the close is not a reset that could
    // discard the answer.
    let mut request = [0u8; 1024];
    let _ = client.read(&mut request);
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// An admitted connection: counted out and told to the server when dropped.
struct Open {
    context: Arc<Context>,
    n: u64,
}

impl Drop for Open {
    fn drop(&mut self) {
        self.context.counts.connected.fetch_sub(1, Ordering::AcqRel);
        self.context.admissions.closed(self.n);
    }
}

impl Open {
    fn relay(self, client: TcpStream, peer: SocketAddr) {
        if let Ok(Some((server, rest))) = self.connect(&client) {
            let _ = self.pass(&client, &server, &rest, peer);
            let _ = server.shutdown(Shutdown::Both);
        }
        let _ = client.shutdown(Shutdown::Both);
    }

    /// Reads the request head and hands it to the crate; once the crate
    /// answered (tungstenite refuses bytes that come with the request), its
    /// answer goes to the client and the mark to the crate. The server's
    /// socket and what the client sent past its head.
    fn connect(&self, client: &TcpStream) -> io::Result<Option<(TcpStream, Vec<u8>)>> {
        client.set_nodelay(true)?;
        let Some((head, rest)) = read_head(client)? else {
            return Ok(None);
        };
        let server = TcpStream::connect_timeout(&self.context.inner, CONNECT_LIMIT)?;
        server.set_nodelay(true)?;
        set_buffer(&server, libc::SO_RCVBUF);
        set_buffer(client, libc::SO_SNDBUF);
        (&server).write_all(&head)?;
        let Some((answer, after)) = read_head(&server)? else {
            return Ok(None);
        };
        (&*client).write_all(&answer)?;
        (&*client).write_all(&after)?;
        if answer.starts_with(b"HTTP/1.1 101") {
            (&server).write_all(&self.context.mark.frame(self.n))?;
        }
        Ok(Some((server, rest)))
    }

    /// Both ways until either ends: the crate's bytes to the client as
    /// they come, the client's frames to the crate within the limit.
    fn pass(
        &self,
        client: &TcpStream,
        server: &TcpStream,
        rest: &[u8],
        peer: SocketAddr,
    ) -> io::Result<()> {
        let (from, to) = (server.try_clone()?, client.try_clone()?);
        let down = std::thread::Builder::new()
            .name("live-gate-out".into())
            .stack_size(THREAD_STACK)
            .spawn(move || {
                let _ = copy(&from, &to);
                let _ = from.shutdown(Shutdown::Both);
                let _ = to.shutdown(Shutdown::Both);
            })?;
        let mut filter = FrameFilter::new(self.context.limits.max_message);
        let mut buffer = vec![0u8; BUFFER];
        let mut next = rest.len();
        buffer[..next].copy_from_slice(rest);
        loop {
            if next > 0 {
                if let Err(length) = filter.pass(&buffer[..next]) {
                    self.oversized(peer, length);
                    break;
                }
                if (&*server).write_all(&buffer[..next]).is_err() {
                    break;
                }
            }
            next = match (&*client).read(&mut buffer) {
                Ok(0) | Err(_) => break,
                Ok(n) => n,
            };
        }
        let _ = server.shutdown(Shutdown::Both);
        let _ = client.shutdown(Shutdown::Both);
        let _ = down.join();
        Ok(())
    }

    fn oversized(&self, peer: SocketAddr, length: u64) {
        let counts = &self.context.counts;
        counts.oversized.fetch_add(1, Ordering::Relaxed);
        if let Some(count) = lock(&self.context.oversized_log).note(Instant::now()) {
            eprintln!(
                "flexloop-live: closed {count} connection(s) (the last from {peer}, a message \
                 of {length} bytes): a client's message may have at most {} bytes \
                 ({} closed in all)",
                self.context.limits.max_message,
                counts.oversized()
            );
        }
    }
}

/// An HTTP head (through its blank line: the client's request, the
/// crate's answer) and what came after it; `None` if it is longer than
/// 8 KiB, does not come within 10 s, or the other side left.
fn read_head(client: &TcpStream) -> io::Result<Option<(Vec<u8>, Vec<u8>)>> {
    let deadline = Instant::now() + HANDSHAKE_LIMIT;
    let mut head = Vec::new();
    let mut chunk = [0u8; 1024];
    let found = loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Ok(None);
        }
        client.set_read_timeout(Some(left))?;
        let n = match (&*client).read(&mut chunk) {
            Ok(0) => return Ok(None),
            Ok(n) => n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(_) => return Ok(None),
        };
        let from = head.len().saturating_sub(3);
        head.extend_from_slice(&chunk[..n]);
        if let Some(at) = head[from..].windows(4).position(|w| w == b"\r\n\r\n") {
            break from + at + 4;
        }
        if head.len() > MAX_REQUEST_HEAD {
            return Ok(None);
        }
    };
    client.set_read_timeout(None)?;
    let rest = head.split_off(found);
    Ok(Some((head, rest)))
}

fn copy(from: &TcpStream, to: &TcpStream) -> io::Result<()> {
    let mut buffer = vec![0u8; BUFFER];
    loop {
        let n = match (&*from).read(&mut buffer) {
            Ok(0) => return Ok(()),
            Ok(n) => n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        (&*to).write_all(&buffer[..n])?;
    }
}

/// Fixes one of the socket's kernel buffers (the kernel doubles the size
/// for its bookkeeping), so that it does not grow with a client that
/// stopped reading. Best effort: the default still works.
fn set_buffer(socket: &TcpStream, which: libc::c_int) {
    let size = SOCKET_BUFFER;
    // SAFETY: a valid descriptor, a c_int option of the size given.
    unsafe {
        libc::setsockopt(
            socket.as_raw_fd(),
            libc::SOL_SOCKET,
            which,
            (&raw const size).cast(),
            std::mem::size_of::<libc::c_int>() as libc::socklen_t,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(opcode: u8, fin: bool, length: u64) -> Vec<u8> {
        let mut h = vec![opcode | if fin { 0x80 } else { 0 }];
        if length < 126 {
            h.push(0x80 | length as u8);
        } else if length <= 0xffff {
            h.push(0x80 | 126);
            h.extend((length as u16).to_be_bytes());
        } else {
            h.push(0x80 | 127);
            h.extend(length.to_be_bytes());
        }
        h.extend([1, 2, 3, 4]);
        h
    }

    #[test]
    fn frames_within_the_limit_pass_in_any_pieces() {
        let mut bytes = header(1, true, 5);
        bytes.extend(b"hello");
        bytes.extend(header(2, true, 60_000));
        bytes.extend(vec![7u8; 60_000]);
        bytes.extend(header(9, true, 0));
        bytes.extend(header(1, false, 30_000));
        bytes.extend(vec![b'x'; 30_000]);
        bytes.extend(header(0, true, 30_000));
        bytes.extend(vec![b'x'; 30_000]);
        for piece in [1, 3, 7, 1000, bytes.len()] {
            let mut filter = FrameFilter::new(MAX_MESSAGE_BYTES);
            for chunk in bytes.chunks(piece) {
                assert_eq!(filter.pass(chunk), Ok(()), "pieces of {piece}");
            }
        }
    }

    #[test]
    fn a_long_frame_or_message_is_stopped_at_its_header() {
        // 15 MB in one frame: refused by its header alone.
        let mut filter = FrameFilter::new(MAX_MESSAGE_BYTES);
        assert_eq!(filter.pass(&header(1, true, 15_000_000)), Err(15_000_000));
        // A length with its top bit set.
        let mut filter = FrameFilter::new(MAX_MESSAGE_BYTES);
        assert!(filter.pass(&header(2, true, u64::MAX)).is_err());
        // Many frames of one message, each within the limit.
        let mut filter = FrameFilter::new(MAX_MESSAGE_BYTES);
        let mut bytes = header(1, false, 40_000);
        bytes.extend(vec![0u8; 40_000]);
        assert_eq!(filter.pass(&bytes), Ok(()));
        assert!(filter.pass(&header(0, true, 40_000)).is_err());
        // A long control frame.
        let mut filter = FrameFilter::new(MAX_MESSAGE_BYTES);
        assert!(filter.pass(&header(9, true, 126)).is_err());
    }

    #[test]
    fn the_mark_names_its_connection_only_with_the_secret() {
        let mark = Mark::new().unwrap();
        let frame = mark.frame(42);
        // A well-formed client frame the filter passes.
        assert_eq!(FrameFilter::new(MAX_MESSAGE_BYTES).pass(&frame), Ok(()));
        let text = String::from_utf8_lossy(&frame);
        let value = text
            .split("\"value\":\"")
            .nth(1)
            .and_then(|v| v.split('"').next())
            .unwrap();
        assert_eq!(mark.connection(value), Some(42));
        assert_eq!(mark.connection("0123:42"), None);
        assert_eq!(Mark::new().unwrap().connection(value), None);
        assert_eq!(mark.connection(&value.replace(":42", ":x")), None);
    }

    #[derive(Default)]
    struct Told(Mutex<Vec<(bool, u64)>>);

    impl Admissions for Told {
        fn opened(&self, n: u64) {
            lock(&self.0).push((true, n));
        }
        fn closed(&self, n: u64) {
            lock(&self.0).push((false, n));
        }
    }

    fn wait_for(what: &str, mut done: impl FnMut() -> bool) {
        let since = Instant::now();
        while !done() {
            assert!(since.elapsed() < Duration::from_secs(10), "{what}");
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// A gate in front of an echo server (what the crate is to it here):
    /// it answers a request head with ANSWER, then sends back what it gets.
    fn echo_gate(limits: Limits) -> (Gate, Arc<Told>) {
        let inner = TcpListener::bind("127.0.0.1:0").unwrap();
        let inner_address = inner.local_addr().unwrap();
        std::thread::spawn(move || {
            for stream in inner.incoming().flatten() {
                std::thread::spawn(move || {
                    if let Ok(Some((_, rest))) = read_head(&stream) {
                        assert!(rest.is_empty(), "bytes came with the request");
                        let _ = (&stream).write_all(ANSWER);
                        let _ = copy(&stream, &stream);
                    }
                });
            }
        });
        let told = Arc::new(Told::default());
        let gate = Gate::start(
            TcpListener::bind("127.0.0.1:0").unwrap(),
            inner_address,
            limits,
            Arc::new(Mark::new().unwrap()),
            Arc::clone(&told) as Arc<dyn Admissions>,
        )
        .unwrap();
        (gate, told)
    }

    const HEAD: &[u8] = b"GET / HTTP/1.1\r\nHost: x\r\n\r\n";
    const ANSWER: &[u8] = b"HTTP/1.1 101 Switching Protocols\r\n\r\n";

    /// A connection through the gate, its answer and mark read.
    fn through(gate: &Gate) -> TcpStream {
        let mut s = TcpStream::connect(gate.address()).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        s.write_all(HEAD).unwrap();
        let mut answer = vec![0u8; ANSWER.len()];
        s.read_exact(&mut answer).unwrap();
        assert_eq!(answer, ANSWER);
        // The mark, sent to the server after its answer, comes back.
        let mut mark = Vec::new();
        while !String::from_utf8_lossy(&mark).contains(MARK_PARAMETER) {
            let mut byte = [0u8; 64];
            let n = s.read(&mut byte).unwrap();
            assert!(n > 0, "no mark");
            mark.extend(&byte[..n]);
        }
        s
    }

    #[test]
    fn connections_beyond_the_cap_are_refused_at_once_and_counted() {
        let limits = Limits {
            max_clients: 3,
            ..Limits::default()
        };
        let (mut gate, told) = echo_gate(limits);
        let mut open: Vec<TcpStream> = (0..3).map(|_| through(&gate)).collect();
        assert_eq!(gate.counts().connected(), 3);
        for _ in 0..20 {
            let mut s = TcpStream::connect(gate.address()).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
            let mut answer = String::new();
            let _ = s.read_to_string(&mut answer);
            assert!(answer.starts_with("HTTP/1.1 503"), "{answer}");
            assert!(answer.contains("at most 3 clients"), "{answer}");
        }
        assert_eq!(gate.counts().refused(), 20);
        assert_eq!(gate.counts().most_connected(), 3);
        drop(open.remove(0));
        wait_for("a slot given back", || gate.counts().connected() == 2);
        open.push(through(&gate));
        assert_eq!(gate.counts().connected(), 3);
        assert_eq!(gate.counts().refused(), 20);
        let said = lock(&told.0).clone();
        assert_eq!(said.iter().filter(|(open, _)| *open).count(), 4);
        assert!(said.contains(&(false, 1)), "{said:?}");
        gate.stop();
        assert!(TcpStream::connect(gate.address()).is_err());
        drop(open);
    }

    #[test]
    fn a_long_message_closes_the_connection_before_it_reaches_the_server() {
        let (gate, _) = echo_gate(Limits::default());
        let mut s = through(&gate);
        let mut frame = header(1, true, 15_000_000);
        frame.extend(vec![b'a'; 100]);
        s.write_all(&frame).unwrap();
        wait_for("closed", || gate.counts().oversized() == 1);
        let mut echoed = Vec::new();
        let _ = s.read_to_end(&mut echoed);
        // Nothing of the long frame reached the server.
        assert!(!echoed.windows(4).any(|w| w == b"aaaa"));
        wait_for("given back", || gate.counts().connected() == 0);
    }

    #[test]
    fn a_client_that_never_sends_its_head_is_not_passed_on() {
        let (gate, told) = echo_gate(Limits::default());
        let mut s = TcpStream::connect(gate.address()).unwrap();
        s.write_all(&vec![b'a'; MAX_REQUEST_HEAD + 2048]).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        let mut answer = Vec::new();
        let _ = s.read_to_end(&mut answer);
        assert!(answer.is_empty());
        wait_for("closed", || lock(&told.0).len() == 2);
    }
}
