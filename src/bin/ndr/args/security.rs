//! A link's security on the command line.

use std::path::PathBuf;

use ndr::net::LinkConfig;
use ndr::net::tls::{self, Fingerprint, TlsConfig};

/// TLS (mutual, TLS 1.3) or the explicit lack of it, for `base` and `remote`.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct SecurityArgs {
    /// This side's certificate (PEM), e.g. from `ndr keygen`.
    #[arg(long, value_name = "FILE", requires = "key")]
    pub cert: Option<PathBuf>,
    /// This side's private key (PEM).
    #[arg(long, value_name = "FILE", requires = "cert")]
    pub key: Option<PathBuf>,
    /// The peer's certificate (PEM): it is pinned by its SHA-256.
    #[arg(long, value_name = "FILE", requires = "cert")]
    pub peer_cert: Option<PathBuf>,
    /// Pin a peer by the SHA-256 of its certificate (as `ndr keygen`
    /// prints it); may be repeated, and combined with --peer-cert.
    #[arg(long, value_name = "SHA256", requires = "cert")]
    pub pin: Vec<Fingerprint>,
    /// Trust any peer whose certificate chains to this CA (PEM) instead.
    #[arg(long, value_name = "FILE", requires = "cert", conflicts_with_all = ["peer_cert", "pin"])]
    pub ca: Option<PathBuf>,
    /// The name the remote's certificate must carry under --ca.
    #[arg(long, default_value = tls::DEFAULT_SERVER_NAME, requires = "ca")]
    pub server_name: String,
    /// Allow a plain (unencrypted, unauthenticated) link with a
    /// non-loopback address.
    #[arg(long, conflicts_with = "cert")]
    pub insecure: bool,
}

impl SecurityArgs {
    /// The TLS configuration, if any, and the insecure switch set in `config`.
    pub fn apply(&self, config: &mut LinkConfig) -> Result<Option<TlsConfig>, String> {
        config.insecure = self.insecure;
        let (Some(cert), Some(key)) = (&self.cert, &self.key) else {
            return Ok(None);
        };
        let tls = if let Some(ca) = &self.ca {
            TlsConfig::from_files_with_ca(cert, key, ca, &self.server_name)
        } else {
            let mut pins = self.pin.clone();
            if let Some(peer) = &self.peer_cert {
                pins.extend(tls::read_fingerprints(peer).map_err(|e| e.to_string())?);
            }
            if pins.is_empty() {
                return Err(
                    "--cert needs the peer: --peer-cert FILE, --pin SHA256 or --ca FILE".into(),
                );
            }
            TlsConfig::from_files_pinned(cert, key, pins)
        };
        let tls = tls.map_err(|e| e.to_string())?;
        eprintln!("ndr: TLS 1.3, this side's sha256 {}", tls.fingerprint());
        Ok(Some(tls))
    }
}
