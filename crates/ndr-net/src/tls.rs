//! Mutual TLS 1.3 on a link: both peers present a certificate.
//!
//! The handshake runs on tokio (tokio-rustls) when the link connects or is
//! accepted, bounded by [`TlsConfig::handshake_timeout`] (and, on a
//! listener, by its pre-authentication budget,
//! [`Admission::preauth_timeout`](crate::Admission::preauth_timeout)); then
//! the rustls connection state goes with the socket to the hub, which
//! carries on with rustls's sans-IO calls (`read_tls`,
//! `process_new_packets`, `reader`, `writer`, `write_tls`) in its own read
//! and write path. A handshake that fails never becomes a
//! [`Link`](crate::Link).
//!
//! A peer is trusted in one of two ways ([`Trust`]):
//!
//! - **pinned**: the SHA-256 of its DER certificate is one of a set
//!   ([`Fingerprint`]). Nothing else of the certificate is checked (names,
//!   dates, issuer): the peer is who holds the key of that exact
//!   certificate. This is what a lab pair made by `ndr keygen` uses, given
//!   either the peer's certificate file or its printed fingerprint.
//! - **CA**: its chain leads to one of the given roots (webpki), and a
//!   server's certificate names the `server_name` given to
//!   [`TlsConfig::from_files_with_ca`].
//!
//! Only TLS 1.3 is offered and accepted, with the `ring` provider.

use std::fmt;
use std::io;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration as StdDuration;

use rustls::client::danger::{HandshakeSignatureValid, ServerCertVerified, ServerCertVerifier};
use rustls::crypto::WebPkiSupportedAlgorithms;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer, ServerName, UnixTime};
use rustls::server::danger::{ClientCertVerified, ClientCertVerifier};
use rustls::{
    AlertDescription, CertificateError, ClientConfig, DigitallySignedStruct, DistinguishedName,
    ServerConfig, SignatureScheme,
};
use tokio::net::TcpStream;

/// Default bound on a TLS handshake.
pub const DEFAULT_HANDSHAKE_TIMEOUT: StdDuration = StdDuration::from_secs(5);
/// Default bound on the handshakes a listener runs at once (with or
/// without TLS).
pub const DEFAULT_MAX_PENDING_HANDSHAKES: usize = 64;
/// The name a server's certificate is checked against under [`Trust::Ca`]
/// unless told otherwise (`ndr keygen` puts it in every certificate).
pub const DEFAULT_SERVER_NAME: &str = "ndr";

/// The SHA-256 of a DER certificate, the way a peer is pinned.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Fingerprint(pub [u8; 32]);

impl Fingerprint {
    /// The fingerprint of a DER certificate.
    #[must_use]
    pub fn of(der: &[u8]) -> Fingerprint {
        let digest = ring::digest::digest(&ring::digest::SHA256, der);
        let mut out = [0; 32];
        out.copy_from_slice(digest.as_ref());
        Fingerprint(out)
    }
}

impl fmt::Display for Fingerprint {
    /// Lowercase hex, bytes separated by colons (as `openssl x509
    /// -fingerprint -sha256` prints it, in lowercase).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, b) in self.0.iter().enumerate() {
            if i > 0 {
                f.write_str(":")?;
            }
            write!(f, "{b:02x}")?;
        }
        Ok(())
    }
}

impl fmt::Debug for Fingerprint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Fingerprint({self})")
    }
}

impl std::str::FromStr for Fingerprint {
    type Err = TlsError;

    /// 64 hex digits, in either case, with or without colons, optionally
    /// after `sha256:` or `SHA256=`.
    fn from_str(s: &str) -> Result<Fingerprint, TlsError> {
        let bad = || TlsError::Fingerprint(s.to_owned());
        let body = s
            .trim()
            .trim_start_matches("sha256:")
            .trim_start_matches("SHA256:")
            .trim_start_matches("sha256=")
            .trim_start_matches("SHA256=");
        let digits: Vec<u8> = body.bytes().filter(|&b| b != b':').collect();
        if digits.len() != 64 {
            return Err(bad());
        }
        let mut out = [0; 32];
        for (i, pair) in digits.chunks_exact(2).enumerate() {
            let text = std::str::from_utf8(pair).map_err(|_| bad())?;
            out[i] = u8::from_str_radix(text, 16).map_err(|_| bad())?;
        }
        Ok(Fingerprint(out))
    }
}

/// How a peer's certificate is trusted.
#[derive(Clone, Debug)]
#[non_exhaustive]
pub enum Trust {
    /// Its chain leads to one of these roots (and a server's certificate
    /// names the `server_name` of [`TlsConfig::from_files_with_ca`]).
    Ca(Vec<CertificateDer<'static>>),
    /// Its certificate's SHA-256 is one of these.
    Pinned(Vec<Fingerprint>),
}

impl Trust {
    /// Any peer whose chain leads to a root in the PEM file `ca`.
    pub fn ca_file(ca: impl AsRef<Path>) -> Result<Trust, TlsError> {
        read_certs(ca.as_ref()).map(Trust::Ca)
    }
}

/// Why TLS could not be set up from the given files or values.
#[non_exhaustive]
pub enum TlsError {
    /// A file could not be read.
    Read {
        /// The file.
        path: String,
        /// What failed.
        error: String,
    },
    /// A certificate file holds no certificate.
    NoCertificate(String),
    /// rustls refused the certificate, key or roots.
    Rustls(String),
    /// Not a SHA-256 fingerprint.
    Fingerprint(String),
    /// Nothing to trust: no fingerprint and no root.
    NoTrust,
}

impl fmt::Display for TlsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TlsError::Read { path, error } => write!(
                f,
                "cannot read {path}: {error} (give PEM files, e.g. from `ndr keygen`)"
            ),
            TlsError::NoCertificate(path) => write!(
                f,
                "{path} holds no PEM certificate (give a .crt file, e.g. from `ndr keygen`)"
            ),
            TlsError::Rustls(e) => write!(
                f,
                "TLS configuration refused: {e} (check that the key matches the certificate)"
            ),
            TlsError::Fingerprint(s) => write!(
                f,
                "{s:?} is not a SHA-256 fingerprint: give 64 hex digits, colons allowed \
                 (`ndr keygen` prints it)"
            ),
            TlsError::NoTrust => f.write_str(
                "no peer to trust: give the peer's certificate, a CA, or a pinned fingerprint",
            ),
        }
    }
}

// `main() -> Result<(), Box<dyn Error>>` and `unwrap` print Debug: the
// message, not the variant, tells the user what to do.
impl fmt::Debug for TlsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(self, f)
    }
}

impl std::error::Error for TlsError {}

/// This side's certificate and key, and whom it trusts: everything a link
/// needs for mutual TLS 1.3. Cheap to clone (the rustls configurations are
/// built once, shared).
#[derive(Clone)]
pub struct TlsConfig {
    client: Arc<ClientConfig>,
    server: Arc<ServerConfig>,
    server_name: ServerName<'static>,
    server_verifier: Arc<dyn ServerCertVerifier>,
    fingerprint: Fingerprint,
    /// Whom a listener lets hold control (every peer it trusts, unless
    /// `observers` is set).
    controllers: Arc<dyn ClientCertVerifier>,
    /// A listener sharing a robot: whom it lets only observe.
    observers: Option<Arc<dyn ClientCertVerifier>>,
    /// This side's chain and key, to rebuild the server's configuration
    /// with another client verifier.
    identity: Arc<(Vec<CertificateDer<'static>>, PrivateKeyDer<'static>)>,
    /// Longest a handshake may take before the connection is dropped; a
    /// listener also waits at most this long for the peer's ClientHello,
    /// and its pre-authentication budget
    /// ([`Admission::preauth_timeout`](crate::Admission::preauth_timeout),
    /// 3 s by default) bounds TLS and ndr's Hello together.
    pub handshake_timeout: StdDuration,
    /// Most handshakes a listener runs at once (at least one). When all
    /// are taken, a new connection takes the slot of one that has stopped
    /// getting further (counted in
    /// [`ListenerStats::evicted`](crate::ListenerStats::evicted)): peers
    /// that never authenticate cannot hold them all. Read when the
    /// listener is bound.
    pub max_pending_handshakes: usize,
}

impl fmt::Debug for TlsConfig {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("TlsConfig")
            .field("fingerprint", &self.fingerprint)
            .field("server_name", &self.server_name)
            .field("handshake_timeout", &self.handshake_timeout)
            .finish_non_exhaustive()
    }
}

impl TlsConfig {
    /// This side's certificate chain and key (PEM files), trusting the
    /// peer whose certificate is in `peer_cert` (PEM) by pinning its
    /// fingerprint: the lab setup of `ndr keygen`.
    pub fn from_files(
        cert: impl AsRef<Path>,
        key: impl AsRef<Path>,
        peer_cert: impl AsRef<Path>,
    ) -> Result<TlsConfig, TlsError> {
        // In argument order: the first missing file is the one reported.
        let chain = read_certs(cert.as_ref())?;
        let key = read_key(key.as_ref())?;
        TlsConfig::new(
            chain,
            key,
            Trust::Pinned(read_fingerprints(peer_cert)?),
            DEFAULT_SERVER_NAME,
        )
    }

    /// This side's certificate chain and key (PEM files), trusting any peer
    /// whose chain leads to a root in `ca` (PEM); a server's certificate must
    /// name `server_name`.
    pub fn from_files_with_ca(
        cert: impl AsRef<Path>,
        key: impl AsRef<Path>,
        ca: impl AsRef<Path>,
        server_name: &str,
    ) -> Result<TlsConfig, TlsError> {
        TlsConfig::new(
            read_certs(cert.as_ref())?,
            read_key(key.as_ref())?,
            Trust::Ca(read_certs(ca.as_ref())?),
            server_name,
        )
    }

    /// This side's certificate chain and key (PEM files), trusting the
    /// peers with these fingerprints.
    pub fn from_files_pinned(
        cert: impl AsRef<Path>,
        key: impl AsRef<Path>,
        pins: Vec<Fingerprint>,
    ) -> Result<TlsConfig, TlsError> {
        TlsConfig::new(
            read_certs(cert.as_ref())?,
            read_key(key.as_ref())?,
            Trust::Pinned(pins),
            DEFAULT_SERVER_NAME,
        )
    }

    /// From DER values: this side's chain (its own certificate first) and
    /// key, whom it trusts, and the name a server's certificate must carry
    /// under [`Trust::Ca`].
    pub fn new(
        cert_chain: Vec<CertificateDer<'static>>,
        key: PrivateKeyDer<'static>,
        trust: Trust,
        server_name: &str,
    ) -> Result<TlsConfig, TlsError> {
        let rustls_err = |e: rustls::Error| TlsError::Rustls(e.to_string());
        let own = cert_chain
            .first()
            .map(|c| Fingerprint::of(c))
            .ok_or_else(|| TlsError::NoCertificate("the certificate chain".into()))?;
        let server_name = ServerName::try_from(server_name.to_owned())
            .map_err(|e| TlsError::Rustls(format!("server name {server_name:?}: {e}")))?;
        let provider = Arc::new(rustls::crypto::ring::default_provider());
        let versions = &[&rustls::version::TLS13];
        let (server_verifier, client_verifier) = verifiers(trust, &provider)?;
        let client = ClientConfig::builder_with_provider(Arc::clone(&provider))
            .with_protocol_versions(versions)
            .map_err(rustls_err)?
            .dangerous()
            .with_custom_certificate_verifier(Arc::clone(&server_verifier))
            .with_client_auth_cert(cert_chain.clone(), key.clone_key())
            .map_err(rustls_err)?;
        let server = server_config(&cert_chain, &key, Arc::clone(&client_verifier))?;
        Ok(TlsConfig {
            client: Arc::new(client),
            server: Arc::new(server),
            server_name,
            server_verifier,
            fingerprint: own,
            controllers: client_verifier,
            observers: None,
            identity: Arc::new((cert_chain, key)),
            handshake_timeout: DEFAULT_HANDSHAKE_TIMEOUT,
            max_pending_handshakes: DEFAULT_MAX_PENDING_HANDSHAKES,
        })
    }

    /// A listener that shares its robot
    /// ([`Admission::observers`](crate::Admission::observers)): also
    /// trusts the peers `observers` names, who may only observe. A base
    /// with such an identity that asks for control is refused (Close
    /// `observer only`, counted in
    /// [`ListenerStats::refused_observer_only`](crate::ListenerStats::refused_observer_only));
    /// an identity on both lists may control.
    pub fn with_observers(mut self, observers: Trust) -> Result<TlsConfig, TlsError> {
        let provider = Arc::new(rustls::crypto::ring::default_provider());
        let (_, observers) = verifiers(observers, &provider)?;
        let either = Arc::new(Either {
            controllers: Arc::clone(&self.controllers),
            observers: Arc::clone(&observers),
        });
        let (chain, key) = &*self.identity;
        self.server = Arc::new(server_config(chain, key, either)?);
        self.observers = Some(observers);
        Ok(self)
    }

    /// Whether the peer that presented `chain` (its own certificate first)
    /// may hold control: any peer this side trusts, unless
    /// [`with_observers`](Self::with_observers) named some who may only
    /// observe — then only a peer the controllers' trust accepts.
    #[must_use]
    pub fn may_control(&self, chain: &[CertificateDer<'_>]) -> bool {
        if self.observers.is_none() {
            return true;
        }
        let Some((end_entity, intermediates)) = chain.split_first() else {
            return false;
        };
        self.controllers
            .verify_client_cert(end_entity, intermediates, UnixTime::now())
            .is_ok()
    }

    /// Whether some peers it trusts may only observe.
    #[must_use]
    pub fn has_observers(&self) -> bool {
        self.observers.is_some()
    }
}

/// A listener's TLS configuration, its clients checked by `client_verifier`.
fn server_config(
    chain: &[CertificateDer<'static>],
    key: &PrivateKeyDer<'static>,
    client_verifier: Arc<dyn ClientCertVerifier>,
) -> Result<ServerConfig, TlsError> {
    let rustls_err = |e: rustls::Error| TlsError::Rustls(e.to_string());
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let mut server = ServerConfig::builder_with_provider(provider)
        .with_protocol_versions(&[&rustls::version::TLS13])
        .map_err(rustls_err)?
        .with_client_cert_verifier(client_verifier)
        .with_single_cert(chain.to_vec(), key.clone_key())
        .map_err(rustls_err)?;
    // No resumption: a link is one long connection, and a ticket would
    // be bytes after the handshake for nothing.
    server.send_tls13_tickets = 0;
    Ok(server)
}

/// A server's certificate's verifier and a client's.
type Verifiers = (Arc<dyn ServerCertVerifier>, Arc<dyn ClientCertVerifier>);

/// The verifiers of `trust`: of a server's certificate, of a client's.
fn verifiers(
    trust: Trust,
    provider: &Arc<rustls::crypto::CryptoProvider>,
) -> Result<Verifiers, TlsError> {
    let rustls_err = |e: rustls::Error| TlsError::Rustls(e.to_string());
    Ok(match trust {
        Trust::Pinned(pins) => {
            if pins.is_empty() {
                return Err(TlsError::NoTrust);
            }
            let pinned = Arc::new(Pinned {
                pins,
                algorithms: provider.signature_verification_algorithms,
            });
            (pinned.clone(), pinned)
        }
        Trust::Ca(roots) => {
            if roots.is_empty() {
                return Err(TlsError::NoTrust);
            }
            let mut store = rustls::RootCertStore::empty();
            for root in roots {
                store.add(root).map_err(rustls_err)?;
            }
            let store = Arc::new(store);
            let server = rustls::client::WebPkiServerVerifier::builder_with_provider(
                Arc::clone(&store),
                Arc::clone(provider),
            )
            .build()
            .map_err(|e| TlsError::Rustls(e.to_string()))?;
            let client = rustls::server::WebPkiClientVerifier::builder_with_provider(
                store,
                Arc::clone(provider),
            )
            .build()
            .map_err(|e| TlsError::Rustls(e.to_string()))?;
            (server, client)
        }
    })
}

impl TlsConfig {
    /// The fingerprint of this side's own certificate (what the peer pins).
    #[must_use]
    pub fn fingerprint(&self) -> Fingerprint {
        self.fingerprint
    }

    /// The same identities, trust and verifiers for a QUIC connection
    /// (TLS 1.3 inside QUIC), offering the ALPN token `alpn`.
    pub(crate) fn quic_client(
        &self,
        alpn: &[u8],
    ) -> Result<quinn_proto::crypto::rustls::QuicClientConfig, TlsError> {
        let mut client = (*self.client).clone();
        client.alpn_protocols = vec![alpn.to_vec()];
        quinn_proto::crypto::rustls::QuicClientConfig::try_from(Arc::new(client))
            .map_err(|e| TlsError::Rustls(format!("QUIC client: {e}")))
    }

    /// The server side of [`quic_client`](Self::quic_client).
    pub(crate) fn quic_server(
        &self,
        alpn: &[u8],
    ) -> Result<quinn_proto::crypto::rustls::QuicServerConfig, TlsError> {
        let mut server = (*self.server).clone();
        server.alpn_protocols = vec![alpn.to_vec()];
        quinn_proto::crypto::rustls::QuicServerConfig::try_from(Arc::new(server))
            .map_err(|e| TlsError::Rustls(format!("QUIC server: {e}")))
    }

    /// The keys of QUIC's stateless resets and of the connection IDs this
    /// side issues, derived from its private key: the same across restarts
    /// of a peer with one identity, so that a restarted remote still knows
    /// the IDs its predecessor issued for its own, and its reset to a
    /// packet of a connection it no longer has carries the token the base
    /// was given: the base ends that connection at once instead of after
    /// its idle timeout.
    pub(crate) fn quic_keys(&self) -> (ring::hmac::Key, u64) {
        let derive = |label: &[u8]| {
            let kdf = ring::hmac::Key::new(ring::hmac::HMAC_SHA256, label);
            ring::hmac::sign(&kdf, self.identity.1.secret_der())
        };
        let reset = derive(b"ndr QUIC stateless reset key v1");
        let cid = derive(b"ndr QUIC connection ID key v1");
        let mut cid_key = [0; 8];
        cid_key.copy_from_slice(&cid.as_ref()[..8]);
        (
            ring::hmac::Key::new(ring::hmac::HMAC_SHA256, reset.as_ref()),
            u64::from_le_bytes(cid_key),
        )
    }

    /// The name the server's certificate must carry under [`Trust::Ca`].
    pub(crate) fn server_name(&self) -> String {
        self.server_name.to_str().into_owned()
    }

    /// A client configuration that presents no certificate (tests of the
    /// refusal; not for use).
    #[doc(hidden)]
    #[must_use]
    pub fn without_client_certificate(&self) -> TlsConfig {
        let provider = Arc::new(rustls::crypto::ring::default_provider());
        let mut out = self.clone();
        if let Ok(builder) = ClientConfig::builder_with_provider(provider)
            .with_protocol_versions(&[&rustls::version::TLS13])
        {
            let verifier = Arc::clone(&self.server_verifier);
            out.client = Arc::new(
                builder
                    .dangerous()
                    .with_custom_certificate_verifier(verifier)
                    .with_no_client_auth(),
            );
        }
        out
    }

    /// Runs the client side of the handshake on `stream` (this side
    /// connected), within the handshake timeout.
    pub(crate) async fn connect(
        &self,
        stream: TcpStream,
    ) -> Result<(TcpStream, rustls::Connection), HandshakeError> {
        let connector = tokio_rustls::TlsConnector::from(Arc::clone(&self.client));
        let handshake = connector.connect(self.server_name.clone(), stream);
        match tokio::time::timeout(self.handshake_timeout, handshake).await {
            Ok(Ok(tls)) => {
                let (stream, conn) = tls.into_inner();
                Ok((stream, conn.into()))
            }
            Ok(Err(e)) => Err(HandshakeError::from_io(&e)),
            Err(_) => Err(HandshakeError::Timeout(self.handshake_timeout)),
        }
    }

    /// Runs the server side of the handshake on `stream` (accepted here),
    /// within the handshake timeout.
    pub(crate) async fn accept(
        &self,
        stream: TcpStream,
    ) -> Result<(TcpStream, rustls::Connection), HandshakeError> {
        let acceptor = tokio_rustls::TlsAcceptor::from(Arc::clone(&self.server));
        match tokio::time::timeout(self.handshake_timeout, acceptor.accept(stream)).await {
            Ok(Ok(tls)) => {
                let (stream, conn) = tls.into_inner();
                Ok((stream, conn.into()))
            }
            Ok(Err(e)) => Err(HandshakeError::from_io(&e)),
            Err(_) => Err(HandshakeError::Timeout(self.handshake_timeout)),
        }
    }
}

/// Why a TLS handshake failed; the link was never set up.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum HandshakeError {
    /// The peer's certificate is not trusted here (unknown issuer, pin
    /// mismatch, bad name), or this side's was refused by the peer.
    UnknownCertificate(String),
    /// The peer presented no certificate (or this side presented none).
    NoCertificate,
    /// The peer does not speak TLS 1.3 (an older TLS, or a plain link).
    Version(String),
    /// The handshake did not finish in time.
    Timeout(StdDuration),
    /// The socket failed or closed during the handshake, or another TLS error.
    Other(String),
}

impl HandshakeError {
    fn from_io(e: &io::Error) -> HandshakeError {
        let Some(err) = e.get_ref().and_then(|r| r.downcast_ref::<rustls::Error>()) else {
            return HandshakeError::Other(e.to_string());
        };
        HandshakeError::from_rustls(err)
    }

    pub(crate) fn from_rustls(err: &rustls::Error) -> HandshakeError {
        match err {
            rustls::Error::InvalidCertificate(c) => {
                HandshakeError::UnknownCertificate(refused_here(c))
            }
            rustls::Error::NoCertificatesPresented
            | rustls::Error::AlertReceived(AlertDescription::CertificateRequired) => {
                HandshakeError::NoCertificate
            }
            // What a peer's TLS sends when its verifier refuses this side's
            // certificate (a pin that does not match is `AccessDenied`).
            rustls::Error::AlertReceived(
                a @ (AlertDescription::BadCertificate
                | AlertDescription::UnknownCA
                | AlertDescription::CertificateUnknown
                | AlertDescription::UnsupportedCertificate
                | AlertDescription::CertificateRevoked
                | AlertDescription::CertificateExpired
                | AlertDescription::AccessDenied
                | AlertDescription::DecryptError),
            ) => HandshakeError::UnknownCertificate(format!(
                "the peer refused this side's certificate ({a:?}): it neither pins it nor \
                 trusts its CA"
            )),
            rustls::Error::AlertReceived(
                a @ (AlertDescription::ProtocolVersion | AlertDescription::HandshakeFailure),
            ) => HandshakeError::Version(format!("{a:?}")),
            rustls::Error::PeerIncompatible(p) => HandshakeError::Version(format!("{p:?}")),
            rustls::Error::InvalidMessage(m) => {
                HandshakeError::Version(format!("not a TLS 1.3 peer: {m:?}"))
            }
            other => HandshakeError::Other(other.to_string()),
        }
    }
}

/// Why this side's verifier refused the peer's certificate, in words.
pub(crate) fn refused_here(c: &CertificateError) -> String {
    let why = match c {
        // What [`Pinned`] returns for a certificate it does not pin.
        CertificateError::ApplicationVerificationFailure => {
            "its SHA-256 matches no pin or peer certificate given here"
        }
        CertificateError::UnknownIssuer => "it does not chain to the CA given here",
        CertificateError::NotValidForName | CertificateError::NotValidForNameContext { .. } => {
            "it does not carry the server name expected here"
        }
        CertificateError::Expired | CertificateError::ExpiredContext { .. } => "it has expired",
        _ => "it is not valid",
    };
    format!("this side refused the peer's certificate: {why} ({c:?})")
}

impl fmt::Display for HandshakeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            HandshakeError::UnknownCertificate(why) => write!(
                f,
                "TLS handshake refused: unknown certificate: {why}; give each side the \
                 other's certificate (--peer-cert) or pin its fingerprint (--pin)"
            ),
            HandshakeError::NoCertificate => f.write_str(
                "TLS handshake refused: no client certificate; both sides need --cert and --key",
            ),
            HandshakeError::Version(why) => write!(
                f,
                "TLS handshake refused: the peer does not speak TLS 1.3 ({why}); configure \
                 TLS on both sides, or neither on loopback"
            ),
            HandshakeError::Timeout(t) => write!(
                f,
                "TLS handshake did not finish within {t:?}; check that the peer runs TLS \
                 and is reachable"
            ),
            HandshakeError::Other(why) => write!(f, "TLS handshake failed: {why}"),
        }
    }
}

impl std::error::Error for HandshakeError {}

/// The fingerprints of the certificates in a PEM file (a peer's `.crt`).
pub fn read_fingerprints(path: impl AsRef<Path>) -> Result<Vec<Fingerprint>, TlsError> {
    Ok(read_certs(path.as_ref())?
        .iter()
        .map(|c| Fingerprint::of(c))
        .collect())
}

fn read_certs(path: &Path) -> Result<Vec<CertificateDer<'static>>, TlsError> {
    let read_err = |e: rustls::pki_types::pem::Error| TlsError::Read {
        path: path.display().to_string(),
        error: e.to_string(),
    };
    let certs = CertificateDer::pem_file_iter(path)
        .map_err(read_err)?
        .collect::<Result<Vec<_>, _>>()
        .map_err(read_err)?;
    if certs.is_empty() {
        return Err(TlsError::NoCertificate(path.display().to_string()));
    }
    Ok(certs)
}

fn read_key(path: &Path) -> Result<PrivateKeyDer<'static>, TlsError> {
    PrivateKeyDer::from_pem_file(path).map_err(|e| TlsError::Read {
        path: path.display().to_string(),
        error: e.to_string(),
    })
}

/// Trusts a peer by its certificate's SHA-256, in both roles; signatures
/// are still checked against that certificate's key.
#[derive(Debug)]
struct Pinned {
    pins: Vec<Fingerprint>,
    algorithms: WebPkiSupportedAlgorithms,
}

impl Pinned {
    fn check(&self, cert: &CertificateDer<'_>) -> Result<(), rustls::Error> {
        if self.pins.contains(&Fingerprint::of(cert)) {
            Ok(())
        } else {
            Err(rustls::Error::InvalidCertificate(
                CertificateError::ApplicationVerificationFailure,
            ))
        }
    }
}

/// The signature checks, the same in both roles: against the presented
/// certificate's key, with the provider's algorithms.
macro_rules! signatures {
    () => {
        fn verify_tls12_signature(
            &self,
            message: &[u8],
            cert: &CertificateDer<'_>,
            dss: &DigitallySignedStruct,
        ) -> Result<HandshakeSignatureValid, rustls::Error> {
            rustls::crypto::verify_tls12_signature(message, cert, dss, &self.algorithms)
        }

        fn verify_tls13_signature(
            &self,
            message: &[u8],
            cert: &CertificateDer<'_>,
            dss: &DigitallySignedStruct,
        ) -> Result<HandshakeSignatureValid, rustls::Error> {
            rustls::crypto::verify_tls13_signature(message, cert, dss, &self.algorithms)
        }

        fn supported_verify_schemes(&self) -> Vec<SignatureScheme> {
            self.algorithms.supported_schemes()
        }
    };
}

impl ServerCertVerifier for Pinned {
    fn verify_server_cert(
        &self,
        end_entity: &CertificateDer<'_>,
        _intermediates: &[CertificateDer<'_>],
        _server_name: &ServerName<'_>,
        _ocsp_response: &[u8],
        _now: UnixTime,
    ) -> Result<ServerCertVerified, rustls::Error> {
        self.check(end_entity)
            .map(|()| ServerCertVerified::assertion())
    }

    signatures!();
}

impl ClientCertVerifier for Pinned {
    fn root_hint_subjects(&self) -> &[DistinguishedName] {
        &[]
    }

    fn verify_client_cert(
        &self,
        end_entity: &CertificateDer<'_>,
        _intermediates: &[CertificateDer<'_>],
        _now: UnixTime,
    ) -> Result<ClientCertVerified, rustls::Error> {
        self.check(end_entity)
            .map(|()| ClientCertVerified::assertion())
    }

    signatures!();
}

/// A shared robot's clients: those either list trusts (whether one may
/// hold control is asked after the handshake,
/// [`TlsConfig::may_control`]).
#[derive(Debug)]
struct Either {
    controllers: Arc<dyn ClientCertVerifier>,
    observers: Arc<dyn ClientCertVerifier>,
}

impl ClientCertVerifier for Either {
    fn root_hint_subjects(&self) -> &[DistinguishedName] {
        // A client picks its certificate by these: both lists' would be
        // the union, which rustls cannot borrow; none lets it offer any.
        &[]
    }

    fn verify_client_cert(
        &self,
        end_entity: &CertificateDer<'_>,
        intermediates: &[CertificateDer<'_>],
        now: UnixTime,
    ) -> Result<ClientCertVerified, rustls::Error> {
        self.controllers
            .verify_client_cert(end_entity, intermediates, now)
            .or_else(|_| {
                self.observers
                    .verify_client_cert(end_entity, intermediates, now)
            })
    }

    fn verify_tls12_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        self.controllers.verify_tls12_signature(message, cert, dss)
    }

    fn verify_tls13_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        self.controllers.verify_tls13_signature(message, cert, dss)
    }

    fn supported_verify_schemes(&self) -> Vec<SignatureScheme> {
        self.controllers.supported_verify_schemes()
    }
}

/// Whether a link to or from `addr` may run without TLS: only on loopback
/// (or when the user said insecure).
#[must_use]
pub fn plain_allowed(addr: std::net::IpAddr, insecure: bool) -> bool {
    insecure || addr.is_loopback()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refused_certificate_names_the_side_that_refused() {
        // A peer whose pin does not match ours alerts AccessDenied.
        let theirs = HandshakeError::from_rustls(&rustls::Error::AlertReceived(
            AlertDescription::AccessDenied,
        ));
        assert!(
            matches!(theirs, HandshakeError::UnknownCertificate(_)),
            "{theirs:?}"
        );
        let msg = theirs.to_string();
        assert!(
            msg.contains("the peer refused this side's certificate"),
            "{msg}"
        );
        let ours = HandshakeError::from_rustls(&rustls::Error::InvalidCertificate(
            CertificateError::ApplicationVerificationFailure,
        ));
        let msg = ours.to_string();
        assert!(
            msg.contains("this side refused the peer's certificate: its SHA-256 matches no pin"),
            "{msg}"
        );
        let ca = refused_here(&CertificateError::UnknownIssuer);
        assert!(ca.contains("CA given here"), "{ca}");
    }

    #[test]
    fn missing_files_are_reported_first_one_first_as_a_message() {
        let e = TlsConfig::from_files(
            "/nonexistent/a.crt",
            "/nonexistent/a.key",
            "/nonexistent/b.crt",
        )
        .unwrap_err();
        let debug = format!("{e:?}");
        assert!(
            debug.starts_with("cannot read /nonexistent/a.crt: "),
            "{debug}"
        );
        assert_eq!(debug, e.to_string());
    }

    #[test]
    fn fingerprints_print_and_parse_back() {
        let f = Fingerprint::of(b"certificate");
        let text = f.to_string();
        assert_eq!(text.len(), 32 * 3 - 1);
        assert_eq!(text.parse::<Fingerprint>().unwrap(), f);
        let bare: String = text.chars().filter(|&c| c != ':').collect();
        assert_eq!(
            format!("sha256:{}", bare.to_uppercase())
                .parse::<Fingerprint>()
                .unwrap(),
            f
        );
        assert!("abc".parse::<Fingerprint>().is_err());
        assert!("zz".repeat(32).parse::<Fingerprint>().is_err());
    }

    #[test]
    fn plain_links_only_on_loopback_unless_insecure() {
        let lo: std::net::IpAddr = "127.0.0.1".parse().unwrap();
        let lo6: std::net::IpAddr = "::1".parse().unwrap();
        let far: std::net::IpAddr = "192.0.2.1".parse().unwrap();
        let any: std::net::IpAddr = "0.0.0.0".parse().unwrap();
        assert!(plain_allowed(lo, false) && plain_allowed(lo6, false));
        assert!(!plain_allowed(far, false) && !plain_allowed(any, false));
        assert!(plain_allowed(far, true));
    }
}
