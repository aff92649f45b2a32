//! The live view's server process (`flexloop live-server`, flexloop-live),
//! started by the supervisor once the loop ticks and stopped before the
//! loop's processes are: a crash of the server (or of the WebSocket stack
//! under it) is never the supervisor's, it runs with the supervisor's CPU
//! and priority (off the loop's), and it dies with the supervisor
//! (PR_SET_PDEATHSIG) (docs/live.md).

use anyhow::Context;
use flexloop_live::{LiveOptions, TOKEN_ENV};
use flexloop_runfiles::RunDir;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The server's stderr, in the run directory.
const STDERR_FILE: &str = "live-server.stderr";
/// How long the server may take to listen before `up` goes on without it.
const START_LIMIT: Duration = Duration::from_secs(10);
const STOP_LIMIT: Duration = Duration::from_secs(3);

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
