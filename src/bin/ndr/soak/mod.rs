//! `ndr soak`: a long run of a fast link through the relay under a schedule
//! of faults, checking that within each connection no sample is lost,
//! duplicated or reordered without a counter saying so, that nothing
//! panics, and that memory stays flat.
//!
//! Three parties: the remote runs as a child process (`ndr soak --serve`,
//! an echo controller that checks the commands it receives), the relay and
//! the base run here. The faults take turns, one every `--fault-every-s`:
//! the relay is restarted (every connection through it is cut), garbage is
//! sent to the remote (a random stream, a wrong version, an absurd length),
//! the remote process is killed (SIGKILL) and started again, a crowd of idle
//! connections is held open on the remote, a base completes its handshake
//! and then hangs (the remote must drop it within its liveness time), and a
//! base sends a stale frame (a repeated sequence number: refused, never
//! released). Throughout, the relay's delay trace adds a 150 ms spike every
//! 0.7 fault periods. After a cut the base connects again; each connection
//! is checked on its own.
//!
//! Over datagrams (`--transport udp`, or `quic`: the same datagrams as QUIC
//! DATAGRAM frames), the relay also loses datagrams by `--loss`: a sample
//! the network lost for good must be counted (`samples_lost`) by the side
//! that missed it, and a repeat or a reordering is never accepted. The
//! garbage fault then also sends stray and spoofed datagrams to the
//! remote's UDP port, which its listener must count as strays while the
//! link goes on.
//!
//! Over QUIC (mutual TLS 1.3), the soak makes throwaway identities for the
//! base and the remote in a fresh temporary directory (removed when it
//! ends), gives the remote its certificate, key and the base's fingerprint
//! on its command line, and each side pins the other. A QUIC remote has no
//! TCP port, so the faults aimed at one take their QUIC form. The garbage
//! connection is a stranger's handshake (a certificate the remote does not
//! pin), which must be refused. The hung base is a base on a UDP path of
//! its own that stops passing what it sends once its handshakes are done:
//! the remote must end it, with Close "timeout", within its liveness time
//! and 3 s. The stale frame is a replayed packet: a base on a path that
//! sends each of its packets again 20 ms later must run for a second with
//! no command repeated or reordered at the remote and no state at the
//! base. There is no idle crowd: its QUIC form, strangers that stop
//! halfway through their handshake, needs a QUIC client the link does not
//! offer. A relay restart need not end a QUIC connection: the remote takes
//! the new relay's address as the base's new path.

mod args;
mod check;
mod faults;
mod link;
mod memory;
mod quic;
mod remote;
mod report;
mod run;
mod serve;
mod trace;

pub use args::SoakArgs;

use link::link_config;
use report::print_table;
use run::soak;
use serve::serve;

use crate::args::millis;
use crate::throwaway::pinned;

pub fn run(args: &SoakArgs) -> Result<(), String> {
    let period = millis("--period-ms", args.period_ms)?;
    if period.is_zero() {
        return Err("--period-ms must be positive".into());
    }
    crate::transport::check_loss(
        args.transport.transport,
        &args.loss,
        "add --transport udp or --transport quic",
    )?;
    let config = link_config(period, args.transport.transport)?;
    if let Some(addr) = args.serve {
        let config = if args.transport.quic {
            let (Some(cert), Some(key), Some(pin)) = (&args.cert, &args.key, args.pin) else {
                return Err(
                    "ndr soak --serve over QUIC needs --cert, --key and --pin (the \
                            base's fingerprint): run `ndr soak --transport quic`, which \
                            makes them and starts its remote with them"
                        .into(),
                );
            };
            config.with_tls(pinned(cert, key, pin)?)
        } else {
            config
        };
        return serve(addr, config);
    }
    for (flag, v) in [
        ("--duration-s", args.duration_s),
        ("--fault-every-s", args.fault_every_s),
    ] {
        if !(v.is_finite() && v > 0.0 && v < 1e7) {
            return Err(format!(
                "{flag} must be a positive number of seconds, got {v}"
            ));
        }
    }
    let report = soak(args, config)?;
    if args.json {
        println!(
            "{}",
            serde_json::to_string(&report).map_err(|e| e.to_string())?
        );
    } else {
        print_table(&report);
    }
    if !report.ok {
        Err("the soak found a problem (see the counters above)".into())
    } else if report.interrupted {
        Err(format!(
            "interrupted after {:.0} s of the {:.0} s asked: the counters above cover that \
             time and found no problem",
            report.ran_s, report.duration_s
        ))
    } else {
        Ok(())
    }
}
