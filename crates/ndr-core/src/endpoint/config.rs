//! What a link endpoint is configured with, and the checks on it.

use core::fmt;
use core::str::FromStr;

use crate::playout::Playout;
use crate::predictor::PredictorConfig;
use crate::regulation::Regulation;
pub use crate::regulation::{Mode, UnknownName};
use crate::sizing::Sizing;
use crate::time::{Duration, Instant};
use crate::wire::{self, MAX_CHANNELS, Role, Seat};

/// How the link carries its samples; both peers must agree.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Transport {
    /// A stream (TCP, TLS): every frame, in order; a lost packet holds the
    /// stream back until it is repaired. The paper's transport.
    #[default]
    Stream,
    /// Datagrams (UDP, QUIC datagrams) for the samples, never sent again:
    /// each carries the newest sample and up to `redundancy − 1` before
    /// it, so that a lost one is recovered from the next. The handshake,
    /// Control and Close still go on a reliable path
    /// ([`Endpoint::handle_frame`](super::Endpoint::handle_frame)); the
    /// driver hands datagrams to
    /// [`Endpoint::handle_datagram`](super::Endpoint::handle_datagram).
    Datagram {
        /// Samples per datagram, 1 to [`MAX_BUNDLE`](crate::wire::MAX_BUNDLE)
        /// (fewer when they would not fit 1200 bytes).
        redundancy: u8,
        /// Times each sample's datagram is sent again, 1 ms
        /// apart (half a period apart where the period is 2 ms or less), 0
        /// to 4, while the path loses datagrams: a
        /// lost datagram is then made good within a millisecond or two
        /// rather than by the next period's copies (which a slow link waits
        /// a whole period for). Only as many as fit in the period before the
        /// next sample go (one at 1 kHz), and only for [`REPEAT_HOLD`] after the first
        /// sample and after each time the peer reports one of this side's
        /// samples missed (every datagram carries the count): a link that
        /// loses nothing sends one datagram a sample.
        repeats: u8,
    },
}

/// Default [`Transport::Datagram::repeats`]: with one datagram in ten
/// lost (5 % on each of two hops), four sends of a sample are all lost
/// once in 10 000, a tenth of the adaptive playout's default late rate (with
/// three, once in 1 000: the playout then waits a period for the copies).
pub(crate) const DEFAULT_REPEATS: u8 = 3;
/// Most [`Transport::Datagram::repeats`].
pub(crate) const MAX_REPEATS: u8 = 4;
/// How long the repeats go on after the first sample, and after each time
/// the peer reports a sample missed: losses come in spells (a busy queue,
/// a radio's fade or hand-over), and repeating through a quiet spell costs
/// only datagrams, where a loss met without repeats waits a period for the
/// next datagram's copies.
pub const REPEAT_HOLD: Duration = Duration::from_secs(10);
/// Between a sample's datagram and its repeats: long enough apart not to
/// share one burst of a queue overflowing, short enough that the delay a
/// repeat adds stays a small part of the round trip.
/// Half a period where that is shorter (`datagram::repeat_spacing`).
pub(crate) const REPEAT_SPACING: Duration = Duration::from_millis(1);

impl Transport {
    /// Datagrams, each with the newest sample and the three before it,
    /// sent 3 more times: with 10 % of datagrams lost
    /// (5 % on each of two hops), a sample and its three copies are all
    /// lost once in 10 000, under the adaptive playout's default late rate
    /// (two copies: once in 1 000, over it).
    pub const DATAGRAM: Transport = Transport::Datagram {
        redundancy: 4,
        repeats: DEFAULT_REPEATS,
    };

    /// Its name: `stream` or `datagram`.
    #[must_use]
    pub(crate) const fn name(self) -> &'static str {
        match self {
            Transport::Stream => "stream",
            Transport::Datagram { .. } => "datagram",
        }
    }
}

impl FromStr for Transport {
    type Err = UnknownName;

    /// `stream` (or `tcp`), `datagram` (or `udp`), `datagram:K` (`K`
    /// samples per datagram, 1 to 8), `datagram:K:R` (each sent `R` more
    /// times, 0 to 4).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let unknown = UnknownName {
            what: "transport",
            valid: "stream (tcp), datagram (udp), datagram:K with K from 1 to 8, \
                    datagram:K:R with R repeats from 0 to 4",
        };
        match s {
            "stream" | "tcp" => Ok(Transport::Stream),
            "datagram" | "udp" => Ok(Transport::DATAGRAM),
            _ => {
                let rest = s
                    .strip_prefix("datagram:")
                    .or_else(|| s.strip_prefix("udp:"))
                    .ok_or(unknown)?;
                let (k, r) = rest.split_once(':').unwrap_or((rest, ""));
                let redundancy = k
                    .parse::<u8>()
                    .ok()
                    .filter(|k| (1..=wire::MAX_BUNDLE).contains(&usize::from(*k)))
                    .ok_or(unknown)?;
                let repeats = if r.is_empty() && !rest.contains(':') {
                    DEFAULT_REPEATS
                } else {
                    r.parse::<u8>()
                        .ok()
                        .filter(|&r| r <= MAX_REPEATS)
                        .ok_or(unknown)?
                };
                Ok(Transport::Datagram {
                    redundancy,
                    repeats,
                })
            }
        }
    }
}

impl fmt::Display for Transport {
    /// The name [`Transport::from_str`] reads back.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Transport::Stream => f.write_str("stream"),
            Transport::Datagram {
                redundancy: 4,
                repeats: DEFAULT_REPEATS,
            } => f.write_str("datagram"),
            Transport::Datagram {
                redundancy,
                repeats: DEFAULT_REPEATS,
            } => write!(f, "datagram:{redundancy}"),
            Transport::Datagram {
                redundancy,
                repeats,
            } => write!(f, "datagram:{redundancy}:{repeats}"),
        }
    }
}

/// The size a datagram's samples are kept within (fewer older samples
/// when they would not fit): what a QUIC datagram holds on any path.
pub(crate) const DATAGRAM_BUDGET: usize = 1200;

/// What a regulator does at a tick whose sample has not arrived.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Underflow {
    /// The paper's FIFO: repeat the last sample and keep every sample, so a
    /// late sample is released one tick later and the delay grows by one
    /// period after each underflow.
    #[default]
    Hold,
    /// Keep the end-to-end delay constant: each sample has a release slot; one
    /// that arrives after its slot is counted late and discarded, and its
    /// tick repeats the last sample.
    DropLate,
}

impl Underflow {
    /// The name used on the command line and in reports.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Underflow::Hold => "hold",
            Underflow::DropLate => "drop-late",
        }
    }
}

impl From<Underflow> for wire::UnderflowCode {
    fn from(underflow: Underflow) -> wire::UnderflowCode {
        match underflow {
            Underflow::Hold => wire::UnderflowCode::Hold,
            Underflow::DropLate => wire::UnderflowCode::DropLate,
        }
    }
}

impl FromStr for Underflow {
    type Err = UnknownName;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "hold" => Ok(Underflow::Hold),
            "drop-late" => Ok(Underflow::DropLate),
            _ => Err(UnknownName {
                what: "underflow policy",
                valid: "hold, drop-late",
            }),
        }
    }
}

impl fmt::Display for Underflow {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// When the paper's dynamic mode decides to change the parameters.
///
/// The base pauses when the forecast period or queue size leaves a band of
/// ±`band` around the current ones, or when the forecast `mt` would empty
/// the queue (`mt ≥ ns·T`: a lag that long uses up the whole stock) —
/// whichever comes first.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Adaptation {
    /// Relative distance between forecast and current parameters that
    /// triggers a resize (0.25: 25 %).
    pub(crate) band: f64,
    /// Periods the predictor runs after a start before it may trigger a
    /// resize (its filters need to settle on the new regime).
    pub(crate) settle_periods: u32,
}

impl Default for Adaptation {
    fn default() -> Self {
        Adaptation {
            band: 0.25,
            settle_periods: 100,
        }
    }
}

/// [`Config::liveness`]'s default: a peer silent this long is gone.
pub const DEFAULT_LIVENESS: Duration = Duration::from_secs(10);

/// Everything an [`Endpoint`](super::Endpoint) needs to know before it starts.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Config {
    /// Base (operator side, sends commands) or remote (robot side, sends states).
    pub role: Role,
    /// Values in each command sample (base → remote), 1 to
    /// [`MAX_CHANNELS`]; both peers must agree.
    pub command_width: u16,
    /// Values in each state sample (remote → base), 1 to [`MAX_CHANNELS`];
    /// both peers must agree.
    pub state_width: u16,
    /// The fingerprint of the application's channel layout
    /// ([`layout::fingerprint`](crate::layout::fingerprint) of its channel
    /// names), `0` for none; both peers must give the same.
    pub layout: u64,
    /// How samples cross: a stream or datagrams; both peers must agree.
    pub transport: Transport,
    /// Datagram transport: this side's session token, which the peer puts
    /// in every datagram it sends here (a datagram with another is
    /// dropped). The driver draws it at random for each link; not `0`.
    pub session: u64,
    /// The sampling period `T`; both peers must agree at the handshake.
    pub period: Duration,
    /// A base: the seat it asks for ([`Seat::Control`] by default). A
    /// remote: the seat it offers a base that asks for control —
    /// [`Seat::Control`] while control is free, [`Seat::Observe`] while
    /// another base holds it (a base asking for control is then refused
    /// with [`LinkError::Busy`](super::LinkError::Busy), one willing to
    /// wait observes). Its driver, which serves every base of the robot,
    /// sets it for each link ([`Floor`](crate::floor::Floor) decides).
    pub seat: Seat,
    /// Static or dynamic sizing of the queues; both peers must agree. With
    /// `playout`, one of the two parts a [`Regulation`] sets
    /// ([`Config::with_regulation`]).
    pub mode: Mode,
    /// What this side's regulator does when a sample is missing at its tick.
    pub underflow: Underflow,
    /// When this side's regulator releases each sample: at a target delay
    /// above its send time chosen from the measured one-way delays
    /// ([`Playout::ADAPTIVE`], the default of [`Config::new`]), in the
    /// paper's FIFO ([`Playout::Fifo`], that of [`Config::paper`]), or by
    /// another [`Playout`]. Each side chooses its own; the peer is not told.
    /// Set it with `mode` through [`Config::with_regulation`]; set the two
    /// fields apart only for a pairing no [`Regulation`] names.
    pub playout: Playout,
    /// The sizing laws (η, `T_min`).
    pub(crate) sizing: Sizing,
    /// Ticks fall on `tick_origin + k·T`. Peers whose clocks agree (a
    /// simulation, or hosts synchronized by PTP or GPS) share one grid, the
    /// paper's "clock common to the whole structure".
    pub tick_origin: Instant,
    /// How long the handshake and each initialization pattern may take, at
    /// least: a pattern (and a pause of the dynamic mode) gets three times
    /// what it needs when that is longer — its probes at the period plus
    /// the slowest round trip seen (3 periods).
    pub handshake_timeout: Duration,
    /// While running, raise [`Event::LinkLost`](super::Event::LinkLost) when no
    /// fresh sample has been released for this long; `None` disables it.
    pub watchdog: Option<Duration>,
    /// After the handshake, end the link with
    /// [`LinkError::PeerSilent`](super::LinkError::PeerSilent) when no frame
    /// has come from the peer for this long (a hung peer, a half-open
    /// connection), so that a listener can serve the next one; `None`
    /// waits for ever. Longer than the watchdog, which raises
    /// [`Event::LinkLost`](super::Event::LinkLost) first.
    pub liveness: Option<Duration>,
    /// Dynamic mode's decision rule.
    pub(crate) adaptation: Adaptation,
    /// The network predictor's time constants, in periods, and horizon
    /// (`period` and `sizing` in it are replaced by this config's).
    pub(crate) predictor: PredictorConfig,
}

impl Config {
    /// ndr's default for `role`: the paper's setup ([`Config::paper`]) with
    /// the adaptive playout at a late rate of 0.1 % ([`Playout::ADAPTIVE`]),
    /// which holds a lower delay than the paper's FIFO at an equal or lower
    /// late rate on every family of `ndr compare` (docs/benchmarks.md).
    #[must_use]
    pub fn new(role: Role) -> Self {
        Config {
            playout: Playout::ADAPTIVE,
            ..Config::paper(role)
        }
    }

    /// The paper's setup for `role`: one value each way, `T = 200 ms`,
    /// static, hold, FIFO.
    #[must_use]
    pub fn paper(role: Role) -> Self {
        let period = Duration::from_millis(200);
        Config {
            role,
            command_width: 1,
            state_width: 1,
            layout: 0,
            transport: Transport::Stream,
            session: 0,
            period,
            seat: Seat::Control,
            mode: Mode::PaperStatic,
            underflow: Underflow::Hold,
            playout: Playout::Fifo,
            sizing: Sizing::default(),
            tick_origin: Instant::ZERO,
            handshake_timeout: Duration::from_secs(10),
            watchdog: Some(Duration::from_secs(1)),
            liveness: Some(DEFAULT_LIVENESS),
            adaptation: Adaptation::default(),
            predictor: PredictorConfig::paper(period),
        }
    }

    /// This configuration regulated by `regulation` (its `mode` and
    /// `playout`).
    #[must_use]
    pub fn with_regulation(mut self, regulation: Regulation) -> Self {
        self.mode = regulation.mode();
        self.playout = regulation.playout();
        self
    }

    /// This configuration with `command_width` values in each command and
    /// `state_width` in each state.
    #[must_use]
    pub fn with_widths(mut self, command_width: u16, state_width: u16) -> Self {
        self.command_width = command_width;
        self.state_width = state_width;
        self
    }

    /// This configuration with `width` values each way (the paper's axes:
    /// a command and a state per axis).
    #[must_use]
    pub fn with_width(self, width: u16) -> Self {
        self.with_widths(width, width)
    }

    /// The width of what this side sends: commands from the base, states
    /// from the remote.
    #[must_use]
    pub const fn sent_width(&self) -> u16 {
        match self.role {
            Role::Base => self.command_width,
            Role::Remote => self.state_width,
        }
    }

    /// The width of what this side receives.
    #[must_use]
    pub const fn received_width(&self) -> u16 {
        match self.role {
            Role::Base => self.state_width,
            Role::Remote => self.command_width,
        }
    }

    /// Checks the values that do not depend on the queue's capacity.
    pub fn validate(&self) -> Result<(), ConfigError> {
        for (width, which) in [(self.command_width, "command"), (self.state_width, "state")] {
            if width == 0 || usize::from(width) > MAX_CHANNELS {
                return Err(ConfigError::Width { which, width });
            }
        }
        if self.period < MIN_PERIOD {
            return Err(ConfigError::Period(self.period));
        }
        let band = self.adaptation.band;
        if !(band.is_finite() && band > 0.0) {
            return Err(ConfigError::Band);
        }
        if self.handshake_timeout.is_zero() {
            return Err(ConfigError::Timeout);
        }
        if self.liveness.is_some_and(|l| l.is_zero()) {
            return Err(ConfigError::Liveness);
        }
        if let Transport::Datagram {
            redundancy,
            repeats,
        } = self.transport
            && (redundancy == 0
                || usize::from(redundancy) > wire::MAX_BUNDLE
                || repeats > MAX_REPEATS
                || self.session == 0)
        {
            return Err(ConfigError::Datagram {
                redundancy,
                repeats,
                session: self.session,
            });
        }
        self.playout.validate().map_err(ConfigError::Playout)
    }

    pub(crate) fn predictor_config(&self) -> PredictorConfig {
        PredictorConfig {
            period: self.period,
            sizing: self.sizing,
            ..self.predictor
        }
    }
}

/// The shortest period an endpoint accepts: 100 µs (10 kHz).
pub const MIN_PERIOD: Duration = Duration::from_micros(100);

/// A configuration that cannot run.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum ConfigError {
    /// A sample width must be in `1..=256`.
    Width {
        /// `"command"` or `"state"`.
        which: &'static str,
        /// The width asked for.
        width: u16,
    },
    /// The endpoint's sample type holds fewer channels than a width.
    Channels {
        /// The wider of the two widths.
        width: u16,
        /// Channels the endpoint's storage holds.
        capacity: usize,
    },
    /// The regulator capacity asked does not fit the endpoint's storage:
    /// an [`Inline<C, N>`](crate::storage::Inline) holds exactly `N`, a
    /// [`Heap`](crate::storage::Heap) 1 to [`MAX_CAPACITY`](crate::storage::MAX_CAPACITY).
    Capacity {
        /// The capacity asked for.
        asked: usize,
    },
    /// The period is shorter than [`MIN_PERIOD`].
    Period(Duration),
    /// The adaptation band must be finite and positive.
    Band,
    /// The handshake timeout must be positive.
    Timeout,
    /// The liveness time must be positive (or `None`).
    Liveness,
    /// The predictor's constants are invalid.
    Predictor(crate::predictor::PredictorError),
    /// The endpoint's storage holds no room for the playout policy asked.
    NoRoom(crate::playout::NoRoom),
    /// A value of the playout policy is out of its range.
    Playout(crate::playout::InvalidPlayout),
    /// The datagram transport needs a redundancy of 1 to
    /// [`MAX_BUNDLE`](crate::wire::MAX_BUNDLE) and a session token other
    /// than 0.
    Datagram {
        /// The redundancy asked for.
        redundancy: u8,
        /// The repeats asked for.
        repeats: u8,
        /// The session token given.
        session: u64,
    },
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            ConfigError::Width { which, width } => write!(
                f,
                "{which} width = {width}: a sample carries 1 to {MAX_CHANNELS} values"
            ),
            ConfigError::Channels { width, capacity } => write!(
                f,
                "a sample of {width} values but this endpoint's samples hold {capacity} channels; \
                 use an Inline<C, N> storage with C >= {width}, or a Heap one"
            ),
            ConfigError::Capacity { asked } => write!(
                f,
                "a regulator capacity of {asked} samples does not fit this endpoint's storage: \
                 an Inline<C, N> storage holds exactly N, a Heap one 1 to {} samples",
                crate::storage::MAX_CAPACITY
            ),
            ConfigError::Period(p) => write!(
                f,
                "period {p} is shorter than the minimum {MIN_PERIOD}; use a longer period"
            ),
            ConfigError::Band => {
                f.write_str("the adaptation band must be finite and positive (e.g. 0.25)")
            }
            ConfigError::Timeout => f.write_str("the handshake timeout must be positive"),
            ConfigError::Liveness => f.write_str(
                "the liveness time must be positive; use None to wait for a silent peer for ever",
            ),
            ConfigError::Predictor(e) => write!(f, "{e}"),
            ConfigError::NoRoom(e) => write!(f, "{e}"),
            ConfigError::Playout(e) => write!(f, "{e}"),
            ConfigError::Datagram {
                redundancy,
                session: 0,
                ..
            } => write!(
                f,
                "the datagram transport needs a session token other than 0 (the driver draws \
                 one at random for each link; redundancy {redundancy})"
            ),
            ConfigError::Datagram {
                redundancy,
                repeats,
                ..
            } => write!(
                f,
                "a datagram redundancy of {redundancy} samples with {repeats} repeats: give \
                 1 to {} samples and 0 to {MAX_REPEATS} repeats",
                wire::MAX_BUNDLE
            ),
        }
    }
}

impl core::error::Error for ConfigError {}
