//! `up --live`: the loop served to Foxglove while it runs (flexloop-live).
//!
//! The server is a process of its own (`flexloop live-server`, hidden),
//! started by the supervisor once the loop ticks and stopped before the
//! loop's processes are: a crash of the server (or of the WebSocket stack
//! under it) is never the supervisor's, it runs with the supervisor's CPU
//! and priority (off the loop's), and it dies with the supervisor
//! (PR_SET_PDEATHSIG). Its tunables go through [`crate::tune`], as
//! `flexloop get`, `set` and `status --scenario` do (docs/live.md).

use crate::tune;
use anyhow::Context;
use flexloop_live::{
    DEFAULT_ADDRESS, HOW_TO_GIVE_A_TOKEN, LiveOptions, LoopSide, OptionsError, SetOutcome,
    TOKEN_ENV, Tuner,
};
use flexloop_runfiles::RunDir;
use std::net::{SocketAddr, TcpListener};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

// The token comes to `up` in its environment (TOKEN_ENV) or a file, and
// travels to the server in the server's environment: never on a command
// line, which every local user can read in /proc/PID/cmdline (a process's
// environment only its own user can).
const STDERR_FILE: &str = "live-server.stderr";
/// How long the server may take to listen before `up` goes on without it.
const START_LIMIT: Duration = Duration::from_secs(10);
const STOP_LIMIT: Duration = Duration::from_secs(3);

/// `up`'s live flags.
#[derive(Debug, Clone, clap::Args)]
pub struct LiveFlags {
    /// Serve the running loop to Foxglove (WebSocket) on ADDR:PORT; give it after
    /// the scenario [default when given alone: 127.0.0.1:8765]
    #[arg(long, value_name = "ADDR:PORT", num_args = 0..=1, default_missing_value = DEFAULT_ADDRESS)]
    pub live: Option<SocketAddr>,
    /// Allow --live on an address other than loopback (the loop is then seen from
    /// other machines; needs a token, FLEXLOOP_LIVE_TOKEN or --live-token-file, or
    /// --live-read-only)
    #[arg(long, requires = "live")]
    pub live_remote: bool,
    /// Refused: a token on the command line is readable by every local user
    #[arg(long, value_name = "TOKEN", hide = true)]
    pub live_token: Option<String>,
    /// Changes of the loop from live clients need the token in this file (its one
    /// line, at least 16 characters; clients set the parameter live.token to it);
    /// or give it in the environment as FLEXLOOP_LIVE_TOKEN
    #[arg(long, value_name = "PATH", requires = "live")]
    pub live_token_file: Option<PathBuf>,
    /// Live clients see the loop and change nothing
    #[arg(long, requires = "live")]
    pub live_read_only: bool,
}

impl LiveFlags {
    /// The checked options; the address is tried before anything starts, so
    /// that a taken port fails `up` instead of leaving a loop without its view.
    pub fn options(&self) -> anyhow::Result<Option<LiveOptions>> {
        if self.live_token.is_some() {
            anyhow::bail!(
                "--live-token: a token on the command line is readable by every local user \
                 (/proc/PID/cmdline); {HOW_TO_GIVE_A_TOKEN}"
            );
        }
        let Some(address) = self.live else {
            return Ok(None);
        };
        let from_env = std::env::var_os(TOKEN_ENV);
        let token = match (&self.live_token_file, from_env) {
            (Some(_), Some(_)) => anyhow::bail!(
                "--live-token-file and {TOKEN_ENV}: two tokens; give one (unset {TOKEN_ENV} \
                 or leave out --live-token-file)"
            ),
            (Some(path), None) => Some(token_from_file(path)?),
            (None, Some(value)) => Some(
                value
                    .into_string()
                    .map_err(|_| anyhow::anyhow!("{TOKEN_ENV}: the token is not UTF-8"))?,
            ),
            (None, None) => None,
        };
        let source = match &self.live_token_file {
            Some(path) => format!("--live-token-file {}", path.display()),
            None => TOKEN_ENV.to_string(),
        };
        let options = LiveOptions::checked(address, self.live_remote, token, self.live_read_only)
            .map_err(|e| match e {
            OptionsError::ShortToken(_) | OptionsError::EmptyToken => {
                anyhow::anyhow!("{source}: {e}")
            }
            e => e.into(),
        })?;
        if address.port() != 0 {
            TcpListener::bind(address)
                .with_context(|| format!("--live {address}: cannot listen there"))?;
        }
        Ok(Some(options))
    }
}

/// The token in `path`: its one line, without the line's end. A file others
/// may read is used, with a warning.
fn token_from_file(path: &Path) -> anyhow::Result<String> {
    use std::os::unix::fs::PermissionsExt;
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("--live-token-file {}", path.display()))?;
    let token = text.trim_end_matches(['\n', '\r']);
    if token.contains(['\n', '\r']) {
        anyhow::bail!(
            "--live-token-file {}: more than one line; the token is the file's one line",
            path.display()
        );
    }
    if let Ok(meta) = std::fs::metadata(path)
        && meta.permissions().mode() & 0o077 != 0
    {
        eprintln!(
            "flexloop: warning: --live-token-file {}: others than its owner may read it \
             (chmod 600)",
            path.display()
        );
    }
    Ok(token.to_string())
}

/// `live-server --prefix P --run-dir D --address A --rate-hz R [--remote] [--read-only]`.
#[derive(Debug, clap::Args)]
pub struct LiveServerArgs {
    #[arg(long)]
    prefix: String,
    #[arg(long)]
    run_dir: PathBuf,
    #[arg(long)]
    address: SocketAddr,
    #[arg(long)]
    rate_hz: f64,
    #[arg(long)]
    remote: bool,
    #[arg(long)]
    read_only: bool,
}

/// The hidden `live-server` command: serves until SIGTERM.
pub fn serve(args: LiveServerArgs) -> anyhow::Result<i32> {
    let token = std::env::var(TOKEN_ENV).ok();
    let options = LiveOptions::checked(args.address, args.remote, token, args.read_only)?;
    let side = LoopSide {
        prefix: args.prefix.clone(),
        run_dir: args.run_dir,
        rate_hz: args.rate_hz,
    };
    let tuner = Arc::new(LoopTuner {
        prefix: args.prefix,
    });
    flexloop_live::serve(options, &side, tuner)?;
    Ok(0)
}

/// The running loop's tunables through `flexloop get`, `set` and `status --scenario`.
struct LoopTuner {
    prefix: String,
}

impl Tuner for LoopTuner {
    fn values(&self) -> Result<Vec<(String, Option<toml::Value>)>, String> {
        tune::values(Some(&self.prefix)).map_err(|e| e.reason)
    }

    fn set(&self, changes: &[(String, String)]) -> Result<SetOutcome, String> {
        let outcome = tune::set(Some(&self.prefix), changes).map_err(|e| e.reason)?;
        Ok(SetOutcome {
            fields: outcome.fields.iter().map(|f| f.field.clone()).collect(),
            summary: tune::outcome_lines(&outcome).join("; "),
        })
    }

    fn scenario(&self) -> Result<(String, String), String> {
        tune::current(Some(&self.prefix))
            .map(|(path, text)| (path.display().to_string(), text))
            .map_err(|e| e.reason)
    }

    fn design(&self, file: &str, text: &str) -> Result<Vec<(String, String)>, String> {
        flexloop_analysis::loop_report::design_words(std::path::Path::new(file), text)
            .map_err(|e| e.to_string())
    }
}

/// The server process of a running loop.
pub struct LiveServer {
    pid: i32,
    run_dir: PathBuf,
    spawned: Instant,
    listening: bool,
    stopped: bool,
}

impl LiveServer {
    /// Starts the server; [`LiveServer::poll`] then says when it listens
    /// (the supervisor's watch goes on meanwhile).
    pub fn spawn(
        options: &LiveOptions,
        prefix: &str,
        run_dir: &Path,
        rate_hz: f64,
    ) -> anyhow::Result<Self> {
        let exe = std::env::current_exe().context("where flexloop is")?;
        let stderr_path = run_dir.join(STDERR_FILE);
        let stderr = std::fs::File::create(&stderr_path)
            .with_context(|| format!("cannot create {}", stderr_path.display()))?;
        let mut cmd = Command::new(exe);
        cmd.arg("live-server")
            .arg("--prefix")
            .arg(prefix)
            .arg("--run-dir")
            .arg(std::path::absolute(run_dir)?)
            .arg("--address")
            .arg(options.address.to_string())
            .arg("--rate-hz")
            .arg(rate_hz.to_string());
        if !options.address.ip().is_loopback() {
            cmd.arg("--remote");
        }
        if options.read_only {
            cmd.arg("--read-only");
        }
        match &options.token {
            Some(token) => cmd.env(TOKEN_ENV, token),
            None => cmd.env_remove(TOKEN_ENV),
        };
        cmd.stdout(Stdio::null());
        crate::children::tied_to_supervisor(&mut cmd, stderr);
        let child = cmd.spawn().context("cannot start flexloop live-server")?;
        Ok(Self {
            pid: child.id() as i32,
            run_dir: run_dir.to_path_buf(),
            spawned: Instant::now(),
            listening: false,
            stopped: false,
        })
    }

    /// Until the server listens: says where once it does, or why the live
    /// view is off (it exited, or did not listen in time; the loop runs on).
    pub fn poll(&mut self) {
        if self.listening || self.stopped {
            return;
        }
        if let Ok(endpoint) = flexloop_live::endpoint(&self.run_dir) {
            self.listening = true;
            eprintln!(
                "flexloop: live view on ws://{}{} (Foxglove: Open connection, Foxglove WebSocket)",
                endpoint.address,
                if endpoint.read_only {
                    ", read-only"
                } else if endpoint.token_required {
                    ", changes need live.token"
                } else {
                    ""
                }
            );
        } else if let Some(code) = self.exited() {
            self.stopped = true;
            let text = std::fs::read_to_string(self.run_dir.join(STDERR_FILE)).unwrap_or_default();
            eprintln!(
                "flexloop: the live view is off: flexloop live-server exited ({code}): {}",
                text.trim()
            );
        } else if self.spawned.elapsed() > START_LIMIT {
            self.stop();
            eprintln!(
                "flexloop: the live view is off: flexloop live-server did not listen within {START_LIMIT:?}"
            );
        }
    }

    /// Its exit status, once it has exited (reaped).
    fn exited(&self) -> Option<i32> {
        let mut status = 0;
        // SAFETY: a child of ours, not reaped yet.
        let rc = unsafe { libc::waitpid(self.pid, &mut status, libc::WNOHANG) };
        (rc == self.pid).then(|| {
            if libc::WIFEXITED(status) {
                libc::WEXITSTATUS(status)
            } else {
                128 + libc::WTERMSIG(status)
            }
        })
    }

    /// Stops it (SIGTERM, then SIGKILL after 3 s) and removes `live.json`.
    pub fn stop(&mut self) {
        if self.stopped {
            return;
        }
        self.stopped = true;
        // SAFETY: a child of ours not yet reaped, so the pid is not reused.
        unsafe { libc::kill(self.pid, libc::SIGTERM) };
        let since = Instant::now();
        let mut code = self.exited();
        while code.is_none() && since.elapsed() < STOP_LIMIT {
            std::thread::sleep(Duration::from_millis(10));
            code = self.exited();
        }
        if code.is_none() {
            // SAFETY: as above.
            unsafe { libc::kill(self.pid, libc::SIGKILL) };
            let mut status = 0;
            // SAFETY: as above; blocks until it is gone (SIGKILL cannot be held off).
            unsafe { libc::waitpid(self.pid, &mut status, 0) };
            eprintln!("flexloop: the live server did not stop within {STOP_LIMIT:?}: killed");
        } else if let Some(code) = code.filter(|c| *c != 0) {
            eprintln!(
                "flexloop: the live server exited with {code} (see {})",
                self.run_dir.join(STDERR_FILE).display()
            );
        }
        let _ = std::fs::remove_file(RunDir::new(&self.run_dir).live());
    }
}

impl Drop for LiveServer {
    fn drop(&mut self) {
        self.stop();
    }
}
