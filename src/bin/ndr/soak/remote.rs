//! The soak's handle on its remote, a child process it starts, asks and
//! kills.

use std::io::{BufRead, BufReader, Write};
use std::net::SocketAddr;
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};

use super::memory;
use crate::transport::LinkTransport;

pub(super) struct Remote {
    pub(super) child: Child,
    pub(super) addr: SocketAddr,
    period_ms: f64,
    transport: LinkTransport,
    /// Over QUIC, its identity and the base's pin: `--cert`, `--key`, `--pin`.
    tls: Vec<String>,
    /// Where it is asked, and answers (see `serve::answer`).
    ask: ChildStdin,
    answers: BufReader<ChildStdout>,
}

impl Remote {
    pub(super) fn start(
        addr: SocketAddr,
        period_ms: f64,
        transport: LinkTransport,
        tls: Vec<String>,
    ) -> Result<Remote, String> {
        // This very binary: on Linux through /proc, which still reaches it
        // when a build has replaced (unlinked) the file it started from.
        let proc_exe = std::path::Path::new("/proc/self/exe");
        let exe = if proc_exe.exists() {
            proc_exe.to_path_buf()
        } else {
            std::env::current_exe().map_err(|e| format!("cannot find ndr itself: {e}"))?
        };
        let mut command = Command::new(exe);
        command
            .args(["soak", "--serve", &addr.to_string()])
            .args(["--period-ms", &period_ms.to_string()])
            .args(["--transport", &transport.to_string()])
            .args(&tls)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null());
        // A group of its own: a Ctrl-C at the terminal is the soak's to
        // handle (it stops the remote in order), not a crash of the remote.
        #[cfg(unix)]
        std::os::unix::process::CommandExt::process_group(&mut command, 0);
        let mut child = command
            .spawn()
            .map_err(|e| format!("cannot start the remote: {e}"))?;
        let mut line = String::new();
        let (Some(ask), Some(stdout)) = (child.stdin.take(), child.stdout.take()) else {
            let _ = child.kill();
            return Err("no pipe to the remote".into());
        };
        let mut answers = BufReader::new(stdout);
        answers
            .read_line(&mut line)
            .map_err(|e| format!("the remote did not start: {e}"))?;
        if line.trim() != "ready" {
            let _ = child.kill();
            return Err(format!("the remote did not start (it said {line:?})"));
        }
        Ok(Remote {
            child,
            addr,
            period_ms,
            transport,
            tls,
            ask,
            answers,
        })
    }

    /// The datagrams its listener counted as strays so far; `None` if it
    /// does not answer (it died).
    pub(super) fn datagrams_stray(&mut self) -> Option<u64> {
        writeln!(self.ask, "stray").ok()?;
        self.ask.flush().ok()?;
        let mut line = String::new();
        self.answers.read_line(&mut line).ok()?;
        line.trim().strip_prefix("stray ")?.parse().ok()
    }

    pub(super) fn rss_kib(&self) -> u64 {
        memory::rss_kib(&format!("/proc/{}/statm", self.child.id()))
    }

    /// Kills it (SIGKILL) and starts another on the same address; `true`
    /// if the old one had died by itself (a crash) before.
    pub(super) fn restart(&mut self) -> Result<bool, String> {
        let crashed = matches!(self.child.try_wait(), Ok(Some(_)));
        let _ = self.child.kill();
        let _ = self.child.wait();
        *self = Remote::start(self.addr, self.period_ms, self.transport, self.tls.clone())?;
        Ok(crashed)
    }
}

impl Drop for Remote {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
