//! A base's side of connecting ([`Link::connect`]): a TCP stream (plain or
//! over TLS), or a QUIC connection, handed to the hub that will drive the
//! link.

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
use crate::runtime::{not_in_a_runtime, own_runtime, plain_allowed};
use crate::tls::TlsConfig;
use crate::transport::Transport;

impl Link {
    /// Connects to a remote (this side is the base) on the current tokio
    /// runtime, over the [`LinkConfig::transport`] (one that does not fit
    /// the TLS is [`NetError::Transport`]): over mutual TLS 1.3 if
    /// [`LinkConfig::tls`] is set (a failed handshake is
    /// [`NetError::Handshake`]; over `quic`, returning once QUIC's handshake
    /// and the Hello are done), else plain, refused with
    /// [`NetError::Insecure`] before connecting unless `addr` is loopback or
    /// [`LinkConfig::insecure`]; driven by the hub [`LinkConfig::hub`] names.
    ///
    /// A remote not there yet is waited for up to
    /// [`LinkConfig::wait_for_remote`]; with [`LinkConfig::reconnect`] the
    /// link connects again by itself when it loses its peer.
    pub async fn connect(addr: SocketAddr, config: LinkConfig) -> Result<Link, NetError> {
        let hub = config.hub.pick(config.spin_margin, config.realtime)?;
        connect_on(&hub, addr, config).await
    }

    /// [`connect`](Self::connect) for programs without a tokio runtime: a
    /// small runtime of its own makes the connection and the handshakes,
    /// and is gone when this returns; the link's hub drives it after that.
    pub fn connect_blocking(addr: SocketAddr, config: LinkConfig) -> Result<Link, NetError> {
        not_in_a_runtime("Link::connect_blocking", "Link::connect(..).await")?;
        let rt = own_runtime()?;
        let hub = config.hub.pick(config.spin_margin, config.realtime)?;
        // Only the connection and the handshakes need the runtime: its hub
        // drives the link, and its thread ends here.
        rt.block_on(connect_on(&hub, addr, config))
    }
}

/// Connects on `hub`, waiting for the remote as `config` says, and makes
/// the link one that reconnects if it asks.
async fn connect_on(hub: &Hub, addr: SocketAddr, config: LinkConfig) -> Result<Link, NetError> {
    let wait: std::time::Duration = config.wait_for_remote.into();
    let (mut link, waited) =
        crate::reconnect::dial_waiting(hub, addr, &config, Some(wait), None).await?;
    link.waited(waited);
    if config.reconnect {
        link.redial_to(addr, config);
    }
    Ok(link)
}

/// Connects as `config` says, and drives the link on `hub`: one attempt.
pub(crate) async fn dial(
    hub: &Hub,
    addr: SocketAddr,
    config: LinkConfig,
) -> Result<Link, NetError> {
    let transport = config.checked_transport(config.tls.is_some())?;
    if transport.is_zenoh() {
        return Err(NetError::Transport(crate::TransportError::ZenohByName));
    }
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
            crate::link::Listened::default(),
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
        crate::link::Listened::default(),
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
    let mut endpoint = crate::quic::endpoint(None, tls);
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
    let started = Link::start_quic(&config, Role::Base, hub, path, None);
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
                "the peer refused this side's certificate (QUIC): it neither pins it nor \
                 trusts its CA"
                    .into(),
            ),
        )),
        Ok(Err(NetError::Link(LinkError::PeerCertificateRefused))) => Err(NetError::Handshake(
            crate::tls::HandshakeError::UnknownCertificate(
                "this side refused the peer's certificate (QUIC): it matches no pin or peer \
                 certificate given here and does not chain to the CA given here"
                    .into(),
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
