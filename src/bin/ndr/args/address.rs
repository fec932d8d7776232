//! Addresses given on the command line.

use std::net::{SocketAddr, ToSocketAddrs};

/// The first address `text` (HOST:PORT) resolves to; the error names `flag`.
pub fn resolve(flag: &str, text: &str) -> Result<SocketAddr, String> {
    let mut addrs = text
        .to_socket_addrs()
        .map_err(|e| format!("{flag} {text}: not an address (HOST:PORT): {e}"))?;
    addrs
        .next()
        .ok_or_else(|| format!("{flag} {text}: resolves to no address"))
}
