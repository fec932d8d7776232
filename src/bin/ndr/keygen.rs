//! `ndr keygen`: a certificate pair for a lab setup, the TLS switches
//! of `ndr base` and `ndr remote`, and the throwaway identities of `ndr
//! demo` and `ndr soak` over QUIC.

use std::path::{Path, PathBuf};

use ndr::keygen::KeyPair;
use ndr::net::LinkConfig;
use ndr::net::tls::{self, Fingerprint, TlsConfig};

#[derive(clap::Args)]
pub struct KeygenArgs {
    /// Directory to write NAME.crt and NAME.key into (created if needed).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// The certificate's name (also its file names), e.g. base or remote.
    #[arg(long, default_value = "ndr")]
    pub name: String,
}

pub fn run(args: &KeygenArgs) -> Result<(), String> {
    let pair = ndr::keygen::write(&args.out, &args.name)?;
    println!("certificate: {}", pair.cert.display());
    println!("key:         {}", pair.key.display());
    println!("sha256:      {}", pair.fingerprint);
    eprintln!(
        "give {} to the peer (--peer-cert), or its fingerprint (--pin); keep the key here",
        pair.cert.display()
    );
    Ok(())
}

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

/// TLS with this side's `cert` and `key`, trusting only the peer whose
/// certificate has the fingerprint `peer` (pinned): mutual TLS 1.3
/// between two throwaway identities.
pub fn pinned(cert: &Path, key: &Path, peer: Fingerprint) -> Result<TlsConfig, String> {
    TlsConfig::from_files_pinned(cert, key, vec![peer]).map_err(|e| e.to_string())
}

/// A fresh temporary directory of this process's (owner only), removed
/// with what it holds when dropped.
struct TempDir(PathBuf);

impl TempDir {
    fn create(what: &str) -> Result<TempDir, String> {
        // The time as well as the process: never a directory left over.
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let dir =
            std::env::temp_dir().join(format!("ndr-{what}-{}-{nanos:09}", std::process::id()));
        let mut builder = std::fs::DirBuilder::new();
        #[cfg(unix)]
        {
            use std::os::unix::fs::DirBuilderExt as _;
            builder.mode(0o700);
        }
        builder.create(&dir).map_err(|e| {
            format!(
                "cannot create {}: {e} (set TMPDIR to a writable directory)",
                dir.display()
            )
        })?;
        Ok(TempDir(dir))
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Throwaway identities for one run over QUIC (`ndr demo`, `ndr soak`): a
/// self-signed pair each for the base and the remote, made by
/// [`ndr::keygen::write`] in a fresh temporary directory, which goes when
/// this is dropped (a failed run's too).
pub struct Throwaway {
    dir: TempDir,
    pub base: KeyPair,
    pub remote: KeyPair,
}

impl Throwaway {
    /// The two pairs, in a directory named after `what` (e.g. `demo`).
    pub fn new(what: &str) -> Result<Throwaway, String> {
        let dir = TempDir::create(what)?;
        let base = ndr::keygen::write(&dir.0, "base")?;
        let remote = ndr::keygen::write(&dir.0, "remote")?;
        Ok(Throwaway { dir, base, remote })
    }

    /// One more pair, `name`, in the same directory (e.g. a stranger's).
    pub fn another(&self, name: &str) -> Result<KeyPair, String> {
        ndr::keygen::write(&self.dir.0, name)
    }

    /// `own`'s TLS, trusting `peer` only.
    pub fn tls(own: &KeyPair, peer: &KeyPair) -> Result<TlsConfig, String> {
        pinned(&own.cert, &own.key, peer.fingerprint)
    }

    /// The base's TLS and the remote's, each pinning the other.
    pub fn pair(&self) -> Result<(TlsConfig, TlsConfig), String> {
        Ok((
            Throwaway::tls(&self.base, &self.remote)?,
            Throwaway::tls(&self.remote, &self.base)?,
        ))
    }
}
