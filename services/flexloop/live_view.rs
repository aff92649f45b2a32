//! `up --live`: the loop served to Foxglove while it runs (flexloop-live).
//!
//! The server is a process of its own (`flexloop live-server`, hidden),
//! started by the supervisor once the loop ticks (flexloop_supervisor::live_server) and stopped before the
//! loop's processes are: a crash of the server (or of the WebSocket stack
//! under it) is never the supervisor's, it runs with the supervisor's CPU
//! and priority (off the loop's), and it dies with the supervisor
//! (PR_SET_PDEATHSIG). Its tunables go through flexloop_supervisor::attach, as
//! `flexloop get`, `set` and `status --scenario` do (docs/live.md).

use anyhow::Context;
use flexloop_live::{
    DEFAULT_ADDRESS, HOW_TO_GIVE_A_TOKEN, LiveOptions, LoopSide, OptionsError, SetOutcome,
    TOKEN_ENV, Tuner,
};
use flexloop_supervisor::attach;
use std::net::{SocketAddr, TcpListener};
use std::path::{Path, PathBuf};
use std::sync::Arc;

// The token comes to `up` in its environment (TOKEN_ENV) or a file, and
// travels to the server in the server's environment
// (flexloop_supervisor::live_server): never on a command line, which every
// local user can read in /proc/PID/cmdline (a process's environment only
// its own user can).

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
        attach::values(Some(&self.prefix)).map_err(|e| e.reason)
    }

    fn set(&self, changes: &[(String, String)]) -> Result<SetOutcome, String> {
        let outcome = attach::set(Some(&self.prefix), changes).map_err(|e| e.reason)?;
        Ok(SetOutcome {
            fields: outcome.fields.iter().map(|f| f.field.clone()).collect(),
            summary: crate::tune::outcome_lines(&outcome).join("; "),
        })
    }

    fn scenario(&self) -> Result<(String, String), String> {
        attach::current(Some(&self.prefix))
            .map(|(path, text)| (path.display().to_string(), text))
            .map_err(|e| e.reason)
    }

    fn design(&self, file: &str, text: &str) -> Result<Vec<(String, String)>, String> {
        flexloop_analysis::loop_report::design_words(std::path::Path::new(file), text)
            .map_err(|e| e.to_string())
    }
}
