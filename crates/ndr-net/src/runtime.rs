//! What the blocking calls and the plain-link check share: the links'
//! and the listeners' side of tokio.

use std::io;
use std::net::SocketAddr;

use tokio::runtime::Handle;

use crate::config::LinkConfig;
use crate::error::NetError;

/// A blocking call made on a tokio runtime's thread would block that
/// runtime (and tokio refuses to run a runtime inside another): an error
/// that names the async call to make instead, rather than tokio's panic.
pub(crate) fn not_in_a_runtime(call: &str, instead: &str) -> Result<(), NetError> {
    match Handle::try_current() {
        Ok(_) => Err(NetError::Io(io::Error::other(format!(
            "{call} was called on a tokio runtime's thread, which it would block: \
             use {instead} there"
        )))),
        Err(_) => Ok(()),
    }
}

/// A small runtime for a blocking call's connection and handshakes.
pub(crate) fn own_runtime() -> Result<tokio::runtime::Runtime, NetError> {
    Ok(tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .thread_name("ndr-io")
        .enable_io()
        .enable_time()
        .build()?)
}

/// Refuses a plain link with a non-loopback address unless insecure.
pub(crate) fn plain_allowed(addr: SocketAddr, config: &LinkConfig) -> Result<(), NetError> {
    if crate::tls::plain_allowed(addr.ip(), config.insecure) {
        Ok(())
    } else {
        Err(NetError::Insecure(addr))
    }
}
