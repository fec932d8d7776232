//! Certificate pairs for a lab setup (`ndr keygen`): a self-signed
//! certificate and its key, as PEM files, and the certificate's SHA-256
//! fingerprint to pin it by.

use std::path::{Path, PathBuf};

use crate::tls::{DEFAULT_SERVER_NAME, Fingerprint};

/// A certificate written by [`write()`].
#[derive(Clone, Debug)]
pub struct KeyPair {
    /// The certificate (PEM).
    pub cert: PathBuf,
    /// Its private key (PEM, readable by its owner only on Unix).
    pub key: PathBuf,
    /// SHA-256 of the DER certificate: what the peer pins.
    pub fingerprint: Fingerprint,
}

/// Makes a self-signed certificate for `name` (its subject alternative
/// names: `name`, the default server name `ndr`, and `localhost`) and
/// writes `dir/name.crt` and `dir/name.key`; refuses to overwrite a key.
pub fn write(dir: &Path, name: &str) -> Result<KeyPair, String> {
    let bad_name = name.is_empty()
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.');
    if bad_name || name.starts_with('.') {
        return Err(format!(
            "certificate name {name:?}: use letters, digits, '-', '_' or '.'"
        ));
    }
    let mut names = vec![name.to_owned()];
    for extra in [DEFAULT_SERVER_NAME, "localhost"] {
        if !names.iter().any(|n| n == extra) {
            names.push(extra.to_owned());
        }
    }
    let pair = rcgen::generate_simple_self_signed(names)
        .map_err(|e| format!("cannot make a certificate: {e}"))?;
    std::fs::create_dir_all(dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    let cert = dir.join(format!("{name}.crt"));
    let key = dir.join(format!("{name}.key"));
    if key.exists() {
        return Err(format!(
            "{} exists: remove it or choose another --name",
            key.display()
        ));
    }
    write_private(&key, &pair.signing_key.serialize_pem())?;
    std::fs::write(&cert, pair.cert.pem())
        .map_err(|e| format!("cannot write {}: {e}", cert.display()))?;
    Ok(KeyPair {
        cert,
        key,
        fingerprint: Fingerprint::of(pair.cert.der()),
    })
}

fn write_private(path: &Path, pem: &str) -> Result<(), String> {
    use std::io::Write as _;
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt as _;
        options.mode(0o600);
    }
    options
        .open(path)
        .and_then(|mut f| f.write_all(pem.as_bytes()))
        .map_err(|e| format!("cannot write {}: {e}", path.display()))
}
