//! Whom a shared remote lets only observe, under TLS.

use std::path::PathBuf;

use ndr::net::tls::{self, Fingerprint, TlsConfig, Trust};

/// The observers' allow-list of `ndr remote --observers`: peers it trusts
/// to watch but not to control, beside the controllers that `--peer-cert`,
/// `--pin` or `--ca` name.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct ObserverTrustArgs {
    /// Under TLS, with --observers: a certificate (PEM) whose holder may
    /// only observe, pinned by its SHA-256; may be repeated. A base with
    /// that identity that asks for control is refused (`observer only`)
    /// and counted (`refused_observer_only`); one also trusted as a
    /// controller (--peer-cert, --pin, --ca) may control.
    #[arg(long, value_name = "FILE", requires_all = ["observers", "cert"])]
    pub observer_cert: Vec<PathBuf>,
    /// Under TLS, with --observers: pin an observer by the SHA-256 of its
    /// certificate (as `ndr keygen` prints it); may be repeated, and
    /// combined with --observer-cert.
    #[arg(long, value_name = "SHA256", requires_all = ["observers", "cert"])]
    pub observer_pin: Vec<Fingerprint>,
    /// Under TLS, with --observers: any peer whose certificate chains to
    /// this CA (PEM) may observe, not control (unless the controllers'
    /// trust takes it too).
    #[arg(
        long,
        value_name = "FILE",
        requires_all = ["observers", "cert"],
        conflicts_with_all = ["observer_cert", "observer_pin"]
    )]
    pub observer_ca: Option<PathBuf>,
}

impl ObserverTrustArgs {
    /// `tls` trusting the observers named, if any were.
    pub fn apply(&self, tls: Option<TlsConfig>) -> Result<Option<TlsConfig>, String> {
        let Some(trust) = self.trust()? else {
            return Ok(tls);
        };
        let Some(tls) = tls else {
            return Err(
                "--observer-cert, --observer-pin and --observer-ca name TLS \
                        identities: give this side's --cert and --key"
                    .into(),
            );
        };
        let kind = match &trust {
            Trust::Ca(_) => "a CA",
            _ => "pinned certificates",
        };
        let tls = tls
            .with_observers(trust)
            .map_err(|e| format!("the observers' allow-list: {e}"))?;
        eprintln!("ndr: observers trusted by {kind}: they may watch, not control");
        Ok(Some(tls))
    }

    fn trust(&self) -> Result<Option<Trust>, String> {
        if let Some(ca) = &self.observer_ca {
            return Trust::ca_file(ca)
                .map(Some)
                .map_err(|e| format!("--observer-ca: {e}"));
        }
        let mut pins = self.observer_pin.clone();
        for cert in &self.observer_cert {
            pins.extend(tls::read_fingerprints(cert).map_err(|e| format!("--observer-cert: {e}"))?);
        }
        Ok((!pins.is_empty()).then_some(Trust::Pinned(pins)))
    }
}
