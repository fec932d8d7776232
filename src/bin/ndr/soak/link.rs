//! The soak's link: the paper's FIFO at a fast period, and the widths of
//! its commands and states.

use ndr::core::endpoint::{Config, Transport, Underflow};
use ndr::core::time::Duration;
use ndr::core::wire::Role;
use ndr::net::LinkConfig;

/// The links' liveness time: a hung base is dropped after it.
pub(super) const LIVENESS: Duration = Duration::from_secs(2);

/// Values in a command: the command itself, the rest zeros.
pub(super) const COMMAND_WIDTH: u16 = 4;
/// Values in a state: the echoed command, then the remote's report on its
/// connection (its gaps, the drops its counters explain, and its datagram
/// counters `samples_lost`, `samples_recovered`, `datagrams_stale`).
pub(super) const STATE_WIDTH: u16 = 6;

pub(super) fn link_config(period: Duration, transport: Transport) -> Result<LinkConfig, String> {
    // The paper's FIFO: what docs/reliability.md's soak runs measured.
    let mut endpoint = Config::paper(Role::Base);
    endpoint = endpoint.with_widths(COMMAND_WIDTH, STATE_WIDTH);
    endpoint.transport = transport;
    endpoint.period = period;
    // A delay spike then costs late samples (dropped and counted) instead of
    // a delay that grows by the spike's length each time.
    endpoint.underflow = Underflow::DropLate;
    endpoint.watchdog = Some(Duration::from_millis(500));
    endpoint.liveness = Some(LIVENESS);
    // The link draws its datagram session token when it starts: any but 0
    // passes the check here.
    let mut checked = endpoint;
    checked.session = checked.session.max(1);
    checked.validate().map_err(|e| e.to_string())?;
    Ok(LinkConfig::new(endpoint))
}
