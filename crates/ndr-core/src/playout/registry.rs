//! The one registry of the built-in policies: each line names a policy's
//! configuration ([`Playout`]'s variant and its values) and the type that
//! runs it, whose [`Entry`] gives its name, how its values read and print,
//! and how it is made. Parsing, names, help texts, [`Builtin`] and its
//! dispatch all come from here.

use core::fmt;
use core::str::FromStr;

use super::adaptive::{Adaptive, AdaptiveSlot};
use super::adaptive_playout::AdaptivePlayout;
use super::classic::{Constant, FixedAboveMin, NetEq, Ramjee1, Ramjee4};
use super::fifo::Fifo;
use super::policy::{
    Admit, Announcement, Arrival, Due, NoRoom, Observed, Outcome, Policy, Room, Setup, Stamps, View,
};
use super::target::OnTicks;
use crate::time::{Duration, Instant};

/// What a registered policy says of itself.
pub(crate) trait Entry: Sized {
    /// Its values, as [`Playout`]'s variant holds them (a tuple).
    type Fields;
    /// Its name: the part before the first `:`.
    const NAME: &'static str;
    /// How it is written, for help texts (`fixed[:MS]`).
    const SYNTAX: &'static str;
    /// What its values are, for messages (empty for none to say).
    const VALUES: &'static str = "";
    /// Its values from what follows `NAME:` (`None`: the bare name).
    fn parse(value: Option<&str>) -> Result<Self::Fields, UnknownPlayout>;
    /// Writes what follows its name.
    fn write_value(fields: &Self::Fields, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let _ = (fields, f);
        Ok(())
    }
    /// Whether values given in Rust are in range.
    fn check(fields: &Self::Fields) -> Result<(), &'static str> {
        let _ = fields;
        Ok(())
    }
    /// The policy for one endpoint.
    fn build(fields: Self::Fields, setup: &Setup) -> Result<Self, NoRoom>;
}

/// A registered policy's name, syntax and values, for help texts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Syntax {
    /// Its name (`fixed`).
    pub(crate) name: &'static str,
    /// How it is written (`fixed[:MS]`).
    pub(crate) syntax: &'static str,
    /// What its values are, or empty.
    pub(crate) values: &'static str,
}

macro_rules! registry {
    ($(
        $(#[$doc:meta])*
        $variant:ident $({ $( $(#[$fdoc:meta])* $field:ident : $fty:ty ),* $(,)? })? => $policy:ty
    ),* $(,)?) => {
        /// How a regulator decides when to release each sample: a built-in
        /// policy by its name and values, or one of the application's own
        /// ([`Playout::Custom`]). An endpoint makes its [`Policy`] from it.
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
        #[non_exhaustive]
        pub enum Playout {
            $( $(#[$doc])* $variant $({ $( $(#[$fdoc])* $field: $fty ),* })?, )*
            /// A policy of the application's own, made by its
            /// [`Factory`](super::Factory) for each endpoint (on
            /// [`Heap`](crate::storage::Heap) storage).
            #[cfg(feature = "alloc")]
            Custom(super::Custom),
        }

        /// Every built-in policy in one value that needs no heap: where an
        /// endpoint keeps a built-in policy, its calls made by a match rather
        /// than through a vtable. The adaptive playout's state is `A`: [`Adaptive`]
        /// (about 7 KiB inline), `Box<Adaptive>` ([`HeapRoom`](super::HeapRoom),
        /// on the heap only when the link runs it), or
        /// [`NoAdaptive`](super::NoAdaptive) for an endpoint that never runs
        /// it.
        // No heap in the core: an endpoint holds one, so the size of the
        // others does not matter.
        #[derive(Clone, Debug)]
        pub struct Builtin<A: AdaptiveSlot = Adaptive>(pub(crate) Policies<A>);

        /// The built-in policies, one variant each.
        #[allow(clippy::large_enum_variant)]
        #[derive(Clone, Debug)]
        pub(crate) enum Policies<A: AdaptiveSlot> {
            $( $(#[$doc])* $variant($policy), )*
        }

        // Each call goes to its policy by a match, not through a vtable:
        // a built-in policy's calls inline into the endpoint.
        impl<A: AdaptiveSlot> Policy for Builtin<A> {
            #[inline]
            fn start(&mut self, ns: usize) -> usize {
                match &mut self.0 { $( Policies::$variant(p) => p.start(ns), )* }
            }
            #[inline]
            fn set_period(&mut self, period: Duration) {
                match &mut self.0 { $( Policies::$variant(p) => p.set_period(period), )* }
            }
            #[inline]
            fn stop(&mut self) {
                match &mut self.0 { $( Policies::$variant(p) => p.stop(), )* }
            }
            #[inline]
            fn arrival(&mut self, arrival: &Arrival, view: &View<'_>) -> Observed {
                match &mut self.0 { $( Policies::$variant(p) => p.arrival(arrival, view), )* }
            }
            #[inline]
            fn floor_moved(&mut self, from: f64, to: f64) {
                match &mut self.0 { $( Policies::$variant(p) => p.floor_moved(from, to), )* }
            }
            #[inline]
            fn admit(&self, sample: &Stamps, now: Instant, view: &View<'_>) -> Admit {
                match &self.0 { $( Policies::$variant(p) => p.admit(sample, now, view), )* }
            }
            #[inline]
            fn queued(&mut self, view: &View<'_>) {
                match &mut self.0 { $( Policies::$variant(p) => p.queued(view), )* }
            }
            #[inline]
            fn lost(&mut self) {
                match &mut self.0 { $( Policies::$variant(p) => p.lost(), )* }
            }
            #[inline]
            fn tick(
                &mut self,
                at: Instant,
                t: Instant,
                next_tick: Option<Instant>,
                view: &View<'_>,
            ) -> Option<Due> {
                match &mut self.0 { $( Policies::$variant(p) => p.tick(at, t, next_tick, view), )* }
            }
            #[inline]
            fn due(&mut self, at: Instant, t: Instant, view: &View<'_>) -> Due {
                match &mut self.0 { $( Policies::$variant(p) => p.due(at, t, view), )* }
            }
            #[inline]
            fn released(&mut self, at: Instant, t: Instant, outcome: Outcome, view: &View<'_>) {
                match &mut self.0 { $( Policies::$variant(p) => p.released(at, t, outcome, view), )* }
            }
            #[inline]
            fn next_release(&self) -> Option<Instant> {
                match &self.0 { $( Policies::$variant(p) => p.next_release(), )* }
            }
            #[inline]
            fn delay(&self) -> Option<Duration> {
                match &self.0 { $( Policies::$variant(p) => p.delay(), )* }
            }
            #[inline]
            fn poll_announcement(&mut self) -> Option<Announcement> {
                match &mut self.0 { $( Policies::$variant(p) => p.poll_announcement(), )* }
            }
            #[inline]
            fn following_tick(&self, plain: Instant) -> Instant {
                match &self.0 { $( Policies::$variant(p) => p.following_tick(plain), )* }
            }
            #[inline]
            fn grid_settled(&self, at: Instant) -> bool {
                match &self.0 { $( Policies::$variant(p) => p.grid_settled(at), )* }
            }
        }

        impl<A: AdaptiveSlot> Builtin<A> {
            /// The policy on the heap.
            #[cfg(feature = "alloc")]
            pub(crate) fn boxed(self) -> alloc::boxed::Box<dyn Policy>
            where
                A: 'static,
            {
                match self.0 {
                    $( Policies::$variant(p) => alloc::boxed::Box::new(p), )*
                }
            }

            fn build(playout: Playout, setup: &Setup) -> Result<Self, NoRoom> {
                match playout {
                    $( Playout::$variant $({ $($field),* })? => Ok(Builtin(Policies::$variant(
                        <$policy as Entry>::build(($($($field,)*)?), setup)?,
                    ))), )*
                    #[cfg(feature = "alloc")]
                    Playout::Custom(_) => Err(NoRoom::Custom),
                }
            }

            fn parse(name: &str, value: Option<&str>) -> Option<Result<Playout, UnknownPlayout>> {
                $( if name == <$policy as Entry>::NAME {
                    return Some(<$policy as Entry>::parse(value).map(
                        |($($($field,)*)?)| Playout::$variant $({ $($field),* })?,
                    ));
                } )*
                None
            }

            fn write(playout: Playout, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                match playout {
                    $( Playout::$variant $({ $($field),* })? => {
                        f.write_str(<$policy as Entry>::NAME)?;
                        <$policy as Entry>::write_value(&($($($field,)*)?), f)
                    } )*
                    #[cfg(feature = "alloc")]
                    Playout::Custom(c) => write!(f, "{c}"),
                }
            }

            fn check(playout: Playout) -> Result<(), &'static str> {
                match playout {
                    $( Playout::$variant $({ $($field),* })? => {
                        <$policy as Entry>::check(&($($($field,)*)?))
                    } )*
                    #[cfg(feature = "alloc")]
                    Playout::Custom(_) => Ok(()),
                }
            }

            fn name_of(playout: Playout) -> Option<&'static str> {
                match playout {
                    $( Playout::$variant { .. } => Some(<$policy as Entry>::NAME), )*
                    #[cfg(feature = "alloc")]
                    Playout::Custom(_) => None,
                }
            }

            const SYNTAX: &'static [Syntax] = &[ $( Syntax {
                name: <$policy as Entry>::NAME,
                syntax: <$policy as Entry>::SYNTAX,
                values: <$policy as Entry>::VALUES,
            }, )* ];
        }
    };
}

registry! {
    /// The paper's FIFO, pre-filled to `ns`, one release per tick.
    Fifo => Fifo,
    /// Ramjee, Kurose, Towsley, Schulzrinne (1994), algorithm 1: `D = d̂ + 4·v̂`
    /// with exponential averages (α = 0.998002) of the delay and its deviation.
    Ramjee1 => OnTicks<Ramjee1>,
    /// Ramjee et al. (1994), algorithm 4: algorithm 1's target with fast
    /// averages (1/8) and spike detection.
    Ramjee4 => OnTicks<Ramjee4>,
    /// A NetEQ-like target: the 0.95 quantile of a histogram of relative
    /// delays (bucket width = period, forget factor 0.983) above the
    /// smallest delay of the last 2–4 s.
    NetEq => OnTicks<NetEq>,
    /// A fixed latency above the smallest delay seen (GStreamer's
    /// rtpjitterbuffer).
    FixedAboveMin {
        /// The latency added to the smallest delay.
        latency: Duration,
    } => OnTicks<FixedAboveMin>,
    /// A constant target delay (the oracle's, on a known trace).
    Constant {
        /// The target.
        delay: Duration,
    } => OnTicks<Constant>,
    /// Timestamp-based: each sample is released at its send time,
    /// mapped to the local clock by the offset and skew estimate
    /// ([`ClockSync`](crate::sync::ClockSync)), plus the `1 − ε` quantile of
    /// the delays above the floor over the last 90–120 s; the target slews
    /// at a bounded rate. A silence past a slot (a stall, whose frames come
    /// in a burst) holds the delay ahead of it while the rise costs less
    /// per sample kept than the quantile would (`Adaptive::sample_cost`)
    /// once half the late budget is used, and whatever it costs once the
    /// window's lost samples reach `ε` of its delays.
    Adaptive {
        /// The target late rate ε, in parts per million (1000 = 0.1 %).
        epsilon_ppm: u32,
        /// The step of the delay asked for, `None` for the default
        /// quantum (the period up to 20 ms, 1 ms beyond) (see
        /// [`delay_quantum`](super::delay_quantum)): a finer one
        /// holds a lower delay that changes more often.
        quantum: Option<Duration>,
    } => AdaptivePlayout<A>,
}

/// The names of the registry, for its own lookups.
type Names = Builtin<Adaptive>;

impl Default for Playout {
    /// The paper's FIFO.
    fn default() -> Self {
        Playout::Fifo
    }
}

impl Playout {
    /// The adaptive policy at its default late rate and quantum.
    pub const ADAPTIVE: Playout = Playout::Adaptive {
        epsilon_ppm: super::adaptive_playout::DEFAULT_EPSILON_PPM,
        quantum: None,
    };

    /// The built-in policies' names, syntax and values, in the registry's
    /// order (for help texts).
    #[must_use]
    pub(crate) fn registered() -> &'static [Syntax] {
        Names::SYNTAX
    }

    /// Its entry in the registry, `None` for a custom policy.
    #[must_use]
    pub(crate) fn syntax(self) -> Option<&'static Syntax> {
        let name = Names::name_of(self)?;
        Names::SYNTAX.iter().find(|s| s.name == name)
    }

    /// Whether its values are in range.
    ///
    /// # Errors
    ///
    /// [`InvalidPlayout`] says which value is not.
    pub fn validate(self) -> Result<(), InvalidPlayout> {
        Names::check(self).map_err(|why| InvalidPlayout { playout: self, why })
    }

    #[cfg(test)]
    /// The quantum the adaptive delay is held in at `period`, `None` for the
    /// other policies.
    #[must_use]
    pub(crate) fn quantum(self, period: Duration) -> Option<Duration> {
        match self {
            Playout::Adaptive { quantum, .. } => Some(super::delay_quantum(period, quantum)),
            _ => None,
        }
    }
}

/// The names of every built-in policy with its values
/// (`fifo, ramjee-1, …, adaptive[:PERCENT[:QUANTUM_MS]] (…)`), for messages.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PlayoutNames;

impl fmt::Display for PlayoutNames {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, s) in Playout::registered().iter().enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            f.write_str(s.syntax)?;
            if !s.values.is_empty() {
                write!(f, " ({})", s.values)?;
            }
        }
        Ok(())
    }
}

/// The name used on the command line and in reports. [`Playout::Constant`]
/// and [`Playout::FixedAboveMin`] carry their value: `constant:120`,
/// `fixed:200` (milliseconds).
impl fmt::Display for Playout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        Names::write(*self, f)
    }
}

/// A name that is not a [`Playout`], or a known one with a value out of
/// its range (the message says which).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UnknownPlayout(Why);

/// What was wrong with a playout's name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Why {
    Name,
    Value(&'static str),
}

impl UnknownPlayout {
    /// No policy has this name.
    pub(crate) const NAME: UnknownPlayout = UnknownPlayout(Why::Name);

    /// A known policy's value out of range: `why` says what it takes.
    pub(crate) const fn value(why: &'static str) -> Self {
        UnknownPlayout(Why::Value(why))
    }

    /// The name itself is unknown (not a value out of a known policy's range).
    #[must_use]
    pub(crate) fn is_unknown_name(self) -> bool {
        self.0 == Why::Name
    }
}

impl fmt::Display for UnknownPlayout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self.0 {
            Why::Name => "unknown playout policy",
            Why::Value(why) => why,
        })?;
        write!(f, "; valid: {PlayoutNames}")
    }
}

impl core::error::Error for UnknownPlayout {}

impl FromStr for Playout {
    type Err = UnknownPlayout;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let (name, value) = match s.trim().split_once(':') {
            None => (s.trim(), None),
            Some((name, value)) => (name, Some(value)),
        };
        Names::parse(name, value).unwrap_or(Err(UnknownPlayout::NAME))
    }
}

/// A [`Playout`] given in Rust with a value out of its range.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct InvalidPlayout {
    playout: Playout,
    why: &'static str,
}

impl InvalidPlayout {
    #[cfg(test)]
    /// The playout refused.
    #[must_use]
    pub(crate) fn playout(&self) -> Playout {
        self.playout
    }
}

impl fmt::Display for InvalidPlayout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} (asked: {})", self.why, self.playout)
    }
}

impl core::error::Error for InvalidPlayout {}

/// Reads a bare name: a policy without values refuses one.
pub(crate) fn bare(value: Option<&str>) -> Result<(), UnknownPlayout> {
    match value {
        None => Ok(()),
        Some(_) => Err(UnknownPlayout::NAME),
    }
}

/// Milliseconds, finite and not negative, to the nanosecond (rounded:
/// `124` is 124 ms exactly).
pub(crate) fn millis(v: &str) -> Option<Duration> {
    match v.trim().parse::<f64>() {
        Ok(ms) if ms.is_finite() && ms >= 0.0 => {
            Some(Duration::from_nanos(libm::round(ms * 1e6) as u64))
        }
        _ => None,
    }
}

/// `units / 10^digits` with the fraction's trailing zeros cut: names are
/// printed from integers, so that no float noise shows (7 000 ppm is
/// `0.7`, not `0.7000000000000001`; 124 ms is `124`).
pub(crate) fn write_decimal(f: &mut fmt::Formatter<'_>, units: u64, digits: u32) -> fmt::Result {
    let scale = 10u64.pow(digits);
    write!(f, "{}", units / scale)?;
    let (mut frac, mut width) = (units % scale, digits as usize);
    if frac > 0 {
        while frac % 10 == 0 {
            frac /= 10;
            width -= 1;
        }
        write!(f, ".{frac:0width$}")?;
    }
    Ok(())
}

/// A duration in milliseconds, as names write it.
pub(crate) fn write_millis(f: &mut fmt::Formatter<'_>, d: Duration) -> fmt::Result {
    write_decimal(f, d.as_nanos(), 6)
}

impl<A: AdaptiveSlot> Room for Builtin<A> {
    fn make(playout: Playout, setup: &Setup) -> Result<Self, NoRoom> {
        Self::build(playout, setup)
    }
}
