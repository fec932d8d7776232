//! The link's settings on the command line.

use ndr::core::Regulation;
use ndr::core::endpoint::{Config, Underflow};
use ndr::core::wire::Role;
use ndr::net::LinkConfig;

use super::time::millis;
use crate::robot::StateLayout;
use crate::transport::LinkTransport;

/// The link's settings, shared by `demo`, `base` and `remote`.
#[derive(clap::Args, Clone, Debug)]
pub struct LinkArgs {
    #[arg(
        long,
        value_name = "NAME",
        help = format!(
            "How the delay is regulated: {} (adaptive: a target delay above each sample's \
             send time, the lowest with a late rate of PERCENT, 0.1 by default; paper-static \
             or paper-dynamic: the paper's FIFO, sized once or resized as the network changes)",
            Regulation::names(Some(Regulation::ADAPTIVE))
        )
    )]
    pub regulation: Option<Regulation>,
    /// What a tick does when its sample has not arrived: hold (the default:
    /// repeat the last sample and keep every one; the paper's FIFO then
    /// releases the late one a tick later) or drop-late (keep the delay
    /// constant: a sample that missed its tick is dropped and counted).
    #[arg(long, default_value = "hold")]
    pub underflow: Underflow,
    /// Sampling period, in ms (50: the paper's choice for its LAN).
    #[arg(long, default_value_t = 50.0)]
    pub period_ms: f64,
    /// Axes of the teleoperated system (1 to 256): a command value each,
    /// and a state value per quantity of --state.
    #[arg(long, default_value_t = 1)]
    pub axes: u16,
    /// What the robot's state holds for each axis: a comma-separated list
    /// of positions, velocities and efforts (the default: positions; e.g.
    /// positions,velocities,efforts is 21 values for 7 axes). Both sides
    /// must give the same: a peer with another layout is refused.
    #[arg(long, default_value = "positions")]
    pub state: StateLayout,
    /// How samples cross: tcp (the paper's stream: a lost packet holds
    /// back every sample behind it until it is resent; the default of base
    /// and remote) or udp[:K[:R]] (datagrams, each with the newest sample
    /// and copies of the K − 1 before it, 4 by default, sent R more times
    /// 1 ms apart, 3 by default, while the peer reports losses, so that a
    /// lost one is made good within a millisecond or two; the handshake
    /// stays on TCP, and the datagrams go to the same port over UDP; the
    /// default of the demo, which runs on loopback) or quic[:K[:R]] (the
    /// same datagrams as QUIC DATAGRAM frames, the handshake on a QUIC
    /// stream, all under mutual TLS 1.3: base and remote need the TLS
    /// options; the demo makes a throwaway pair) or zenoh[:K[:R]] (the same
    /// datagrams as zenoh publications, through a zenoh router or between
    /// zenoh peers, the robot found by its name: --name, --robot,
    /// --zenoh-connect; in a build with the zenoh feature). UDP is plain:
    /// loopback, or --insecure, and not with TLS.
    #[arg(long)]
    pub transport: Option<LinkTransport>,
    #[command(flatten)]
    pub realtime: super::RealtimeArgs,
}

impl LinkArgs {
    /// `--transport`, or the paper's stream when it was not given.
    pub fn transport(&self) -> LinkTransport {
        self.transport.unwrap_or_default()
    }

    pub fn config(&self) -> Result<LinkConfig, String> {
        let period = millis("--period-ms", self.period_ms)?;
        if period.is_zero() {
            return Err("--period-ms must be positive".into());
        }
        let states = self.state.width(self.axes)?;
        let mut endpoint = Config::new(Role::Base).with_widths(self.axes, states);
        endpoint.layout = self.state.fingerprint(self.axes);
        endpoint.period = period;
        let regulation = self.regulation();
        endpoint.mode = regulation.mode();
        endpoint.playout = regulation.playout();
        endpoint.underflow = self.underflow;
        // The link draws its datagram session token when it starts.
        let mut checked = endpoint;
        checked.session = checked.session.max(1);
        checked.validate().map_err(|e| e.to_string())?;
        let mut config = LinkConfig::new(endpoint).with_transport(self.transport());
        self.realtime.apply(&mut config)?;
        Ok(config)
    }

    /// `--regulation`, or the adaptive default.
    pub fn regulation(&self) -> Regulation {
        self.regulation.unwrap_or_default()
    }

    /// The regulation's name, for reports.
    pub fn regulation_name(&self) -> String {
        self.regulation().to_string()
    }

    /// This side's playout's name, for reports.
    pub fn playout_name(&self) -> String {
        self.regulation().playout().to_string()
    }
}

#[cfg(test)]
mod tests {
    use clap::Parser;
    use ndr::core::endpoint::Mode;
    use ndr::core::playout::Playout;

    use super::LinkArgs;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        link: LinkArgs,
    }

    fn link(args: &[&str]) -> LinkArgs {
        Cli::try_parse_from([&["ndr"][..], args].concat())
            .expect("the flags parse")
            .link
    }

    #[test]
    fn the_regulation_sets_the_mode_and_the_playout() {
        let cases: [(&[&str], Mode, Playout, &str); 4] = [
            (&[], Mode::PaperStatic, Playout::ADAPTIVE, "adaptive"),
            (
                &["--regulation", "paper-static"],
                Mode::PaperStatic,
                Playout::Fifo,
                "paper-static",
            ),
            (
                &["--regulation", "paper-dynamic"],
                Mode::PaperDynamic,
                Playout::Fifo,
                "paper-dynamic",
            ),
            (
                &["--regulation", "neteq"],
                Mode::PaperStatic,
                Playout::NetEq,
                "neteq",
            ),
        ];
        for (args, mode, playout, name) in cases {
            let l = link(args);
            let c = l.config().expect("a valid configuration").endpoint;
            assert_eq!((c.mode, c.playout), (mode, playout), "{args:?}");
            assert_eq!(l.regulation_name(), name, "{args:?}");
        }
        // Base and remote run the paper's stream unless told otherwise.
        assert_eq!(link(&[]).transport().to_string(), "tcp");
    }

    #[test]
    fn a_wrong_name_or_an_old_flag_is_an_error() {
        let err = Cli::try_parse_from(["ndr", "--regulation", "fifo"])
            .err()
            .expect("fifo is no regulation")
            .to_string();
        assert!(
            err.contains("paper-static") && err.contains("paper-dynamic"),
            "{err}"
        );
        for old in ["--mode", "--playout"] {
            assert!(
                Cli::try_parse_from(["ndr", old, "paper-static"]).is_err(),
                "{old}"
            );
        }
    }
}
