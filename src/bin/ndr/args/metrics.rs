//! `--metrics`: where to serve the Prometheus page.

use std::net::SocketAddr;

use super::resolve;

/// The metrics endpoint of `demo`, `base`, `remote` and `relay`.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct MetricsArgs {
    /// Serve the link's figures as Prometheus text at
    /// http://HOST:PORT/metrics while the command runs: counters, gauges
    /// and a histogram of release lateness, labelled per link (peer, role,
    /// transport); see docs/guide/metrics.md. A bare PORT serves on
    /// loopback (127.0.0.1); PORT 0 takes a free port, printed on stderr.
    #[arg(long, value_name = "HOST:PORT")]
    pub metrics: Option<String>,
}

impl MetricsArgs {
    /// The address to serve on, if any; a bare port means loopback.
    pub fn address(&self) -> Result<Option<SocketAddr>, String> {
        let Some(text) = &self.metrics else {
            return Ok(None);
        };
        if let Ok(port) = text.parse::<u16>() {
            return Ok(Some(SocketAddr::from(([127, 0, 0, 1], port))));
        }
        resolve("--metrics", text).map(Some)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bare_port_is_loopback_and_an_address_is_taken_as_given() {
        let args = |s: &str| MetricsArgs {
            metrics: Some(s.into()),
        };
        assert_eq!(
            args("9464").address().unwrap(),
            Some("127.0.0.1:9464".parse().unwrap())
        );
        assert_eq!(
            args("0.0.0.0:9464").address().unwrap(),
            Some("0.0.0.0:9464".parse().unwrap())
        );
        assert!(args("nowhere").address().unwrap_err().contains("--metrics"));
        assert_eq!(MetricsArgs::default().address().unwrap(), None);
    }
}
