//! Throwaway TLS identities for one run over QUIC (`ndr demo`, `ndr soak`).

use std::path::{Path, PathBuf};

use ndr::keygen::KeyPair;
use ndr::net::tls::{Fingerprint, TlsConfig};

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
