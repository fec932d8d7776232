//! `ndr soak`'s options.

use std::net::SocketAddr;
use std::path::PathBuf;

use ndr::net::Fingerprint;
use ndr::sim::delay::LossModel;

use crate::transport::LinkTransport;

#[derive(clap::Args)]
pub struct SoakArgs {
    /// How long to run, in seconds.
    #[arg(long, default_value_t = 60.0)]
    pub duration_s: f64,
    /// The link's period, in ms (1: a 1 kHz link).
    #[arg(long, default_value_t = 1.0)]
    pub period_ms: f64,
    /// Seconds between two faults (relay restart, garbage, remote killed,
    /// idle connections, a hung base, a stale frame, in turn; over QUIC,
    /// their QUIC forms, and no idle connections).
    #[arg(long, default_value_t = 10.0)]
    pub fault_every_s: f64,
    /// How samples cross: tcp (the default), udp[:K[:R]] (datagrams,
    /// each with the newest sample and copies of the K − 1 before it, sent
    /// R more times; see `ndr demo --help`) or quic[:K[:R]] (the same
    /// datagrams over QUIC, mutual TLS 1.3: the soak makes throwaway
    /// identities for both sides, each pinning the other's). The remote
    /// runs the same.
    #[arg(long, default_value = "tcp")]
    pub transport: LinkTransport,
    /// Datagrams the relay loses, each way: none, PERCENT (each
    /// independently, e.g. 2) or ge:PERCENT:BURST (in bursts of BURST on
    /// average, e.g. ge:2:4). Needs --transport udp or quic: the relay
    /// never drops TCP bytes.
    #[arg(long, default_value = "none")]
    pub loss: LossModel,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Internal: be the remote, listening on ADDR (the soak starts itself so).
    #[arg(long, hide = true, value_name = "ADDR")]
    pub serve: Option<SocketAddr>,
    /// Internal, the remote over QUIC: its certificate, its key, and the
    /// fingerprint of the base's certificate it pins (the soak makes them).
    #[arg(long, hide = true, value_name = "FILE", requires = "serve")]
    pub cert: Option<PathBuf>,
    #[arg(long, hide = true, value_name = "FILE", requires = "serve")]
    pub key: Option<PathBuf>,
    #[arg(long, hide = true, value_name = "SHA256", requires = "serve")]
    pub pin: Option<Fingerprint>,
}
