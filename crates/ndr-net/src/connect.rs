//! A base's side of connecting: a TCP stream (plain or over TLS), or a
//! QUIC connection, handed to the hub that will drive the link.

use std::io;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Instant as StdInstant;

use ndr_core::endpoint::LinkError;
use ndr_core::wire::Role;
use tokio::net::TcpStream;
use tokio::runtime::Handle;

use crate::config::LinkConfig;
use crate::error::NetError;
use crate::hub::{Hub, Msg, NewEndpoint, NewSocket, QuicPath, bind_datagram_socket};
use crate::link::Link;
use crate::runtime::plain_allowed;
use crate::tls::TlsConfig;
use crate::transport::Transport;

/// Connects as `config` says, and drives the link on `hub`.
pub(crate) async fn dial(
    hub: &Hub,
    addr: SocketAddr,
    config: LinkConfig,
) -> Result<Link, NetError> {
    let transport = config.checked_transport(config.tls.is_some())?;
    let Some(tls) = config.tls.clone() else {
        plain_allowed(addr, &config)?;
        let stream = TcpStream::connect(addr).await?;
        return Link::start(
            stream,
            Role::Base,
            config,
            Handle::current(),
            hub,
            None,
            None,
        );
    };
    if let Transport::Quic { .. } = transport {
        return quic(hub, addr, config, &tls).await;
    }
    let stream = TcpStream::connect(addr).await?;
    let (stream, conn) = tls.connect(stream).await.map_err(NetError::Handshake)?;
    Link::start(
        stream,
        Role::Base,
        config,
        Handle::current(),
        hub,
        Some(conn),
        None,
    )
}

/// A QUIC link to `addr` from an endpoint (and UDP socket) of its own,
/// returned once the QUIC handshake and ndr's Hello are done (or have
/// failed: an unknown certificate is [`NetError::Handshake`]).
async fn quic(
    hub: &Hub,
    addr: SocketAddr,
    config: LinkConfig,
    tls: &TlsConfig,
) -> Result<Link, NetError> {
    let client = crate::quic::client(&config.endpoint, tls)
        .map_err(|e| NetError::Handshake(crate::tls::HandshakeError::Other(e.to_string())))?;
    let any: SocketAddr = if addr.is_ipv6() {
        (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
    } else {
        (std::net::Ipv4Addr::UNSPECIFIED, 0).into()
    };
    let socket = bind_datagram_socket(any)?;
    let mut endpoint = crate::quic::endpoint(None);
    let (handle, conn) = endpoint
        .connect(StdInstant::now(), client, addr, &tls.server_name())
        .map_err(|e| NetError::Io(io::Error::other(format!("QUIC connect to {addr}: {e}"))))?;
    let key = hub.next_id();
    let new = NewSocket {
        socket,
        stray: Arc::default(),
        held: true,
    };
    let point = NewEndpoint {
        endpoint,
        server: None,
        socket: None,
    };
    if !hub.send(Msg::Quic(key, Box::new(new), Box::new(point))) {
        return Err(NetError::Io(io::Error::other(
            "the hub's thread has stopped",
        )));
    }
    let path = QuicPath::new(key, handle, conn);
    let started = Link::start_quic(&config, Role::Base, hub, path);
    let (id, entry, mut link) = match started {
        Ok(started) => started,
        Err(e) => {
            let _ = hub.send(Msg::ReleaseSocket(key));
            return Err(e);
        }
    };
    if !hub.send(Msg::Add(id, Box::new(entry))) {
        return Err(NetError::Io(io::Error::other(
            "the link's hub thread has stopped",
        )));
    }
    let wait = tls.handshake_timeout;
    match tokio::time::timeout(wait, link.handshake()).await {
        Ok(Ok(())) => Ok(link),
        Ok(Err(NetError::Link(LinkError::CertificateRefused))) => Err(NetError::Handshake(
            crate::tls::HandshakeError::UnknownCertificate(
                "QUIC: a certificate was refused by this side or the peer".into(),
            ),
        )),
        Ok(Err(e)) => Err(e),
        Err(_) => {
            link.dismiss(LinkError::Timeout);
            Err(NetError::Handshake(crate::tls::HandshakeError::Timeout(
                wait,
            )))
        }
    }
}
