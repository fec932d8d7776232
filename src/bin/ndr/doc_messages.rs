//! Every message `ndr base` and `ndr remote` word themselves (how a run
//! or a session ended, the hints of [`crate::explain`]) has its entry in
//! docs/guide/troubleshooting.md; the library's messages are checked there
//! by ndr-core's and ndr-net's tests.

use std::net::SocketAddr;

use ndr::core::endpoint::LinkError;
use ndr::core::wire::CloseReason;
use ndr::net::NetError;

use crate::report::End;
use crate::robot::SessionEnd;
use crate::transport::LinkTransport;

fn every_message() -> Vec<String> {
    let to: SocketAddr = "192.0.2.7:7300".parse().unwrap();
    let why = || "…".to_string();
    let ends = vec![
        End::Completed,
        End::NeverConnected(why()),
        End::Refused {
            reason: "busy",
            why: why(),
        },
        End::LinkFailed(why()),
        End::PeerEnded(why()),
        End::AppFailure(why()),
        End::NotGranted(why()),
    ];
    let sessions = vec![
        SessionEnd::Stopped,
        SessionEnd::Ended(LinkError::PeerClosed {
            reason: CloseReason::Normal,
        }),
        SessionEnd::Ended(LinkError::PeerClosed {
            reason: CloseReason::Application,
        }),
        SessionEnd::Ended(LinkError::PeerClosed {
            reason: CloseReason::ProtocolError,
        }),
        SessionEnd::Ended(LinkError::Disconnected),
        SessionEnd::Ended(LinkError::PeerSilent {
            silent_for: ndr::core::time::Duration::from_secs(10),
        }),
        SessionEnd::Ended(LinkError::Timeout),
        SessionEnd::Ended(LinkError::Closed),
        SessionEnd::AppFailure(why()),
    ];
    // No wildcard: a new way to end fails to compile here until it has
    // its sample above (and its entry in the page).
    for e in &ends {
        match e {
            End::Completed
            | End::NeverConnected(_)
            | End::Refused { .. }
            | End::LinkFailed(_)
            | End::PeerEnded(_)
            | End::AppFailure(_)
            | End::NotGranted(_) => {}
        }
    }
    for s in &sessions {
        match s {
            SessionEnd::Stopped | SessionEnd::Ended(_) | SessionEnd::AppFailure(_) => {}
        }
    }
    let refused = NetError::Io(std::io::ErrorKind::ConnectionRefused.into());
    let mut all: Vec<String> = ends
        .iter()
        .filter(|e| !e.ok())
        .map(ToString::to_string)
        .chain(sessions.iter().map(ToString::to_string))
        .collect();
    all.push(crate::explain::cannot_connect(
        &refused,
        to,
        LinkTransport::Tcp,
    ));
    all.push(
        crate::explain::udp_silence(End::NeverConnected(why()), LinkTransport::UDP, to, None)
            .to_string(),
    );
    all.push(crate::robot::session_line(
        &SessionEnd::Stopped,
        None,
        LinkTransport::UDP,
        7300,
    ));
    for tls in [false, true] {
        for t in [LinkTransport::UDP, LinkTransport::QUIC] {
            all.extend(crate::transport::check_security(t, tls).err());
        }
    }
    all
}

include!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/support/troubleshooting_page.rs"
));

#[test]
fn every_message_of_base_and_remote_is_in_the_troubleshooting_page() {
    troubleshooting_page::assert_listed(
        concat!(env!("CARGO_MANIFEST_DIR"), "/docs/guide/troubleshooting.md"),
        every_message(),
    );
}
