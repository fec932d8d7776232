//! How the delay is regulated: the one name a user gives, the same in Rust,
//! on the command line (`--regulation`), in Python (`regulation=`) and in
//! JSON reports (`"regulation"`).

use core::fmt;
use core::str::FromStr;

use crate::playout::{Playout, UnknownPlayout};
use crate::wire;

/// How the regulators are sized: the part of a regulation both peers must
/// agree on (it travels in the Hello).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Mode {
    /// The paper's static NDR: the initialization pattern sizes the queues once.
    #[default]
    PaperStatic,
    /// The paper's dynamic NDR: the network predictor watches the link, and
    /// when its forecast leaves a band around the current parameters the
    /// peers pause, run a new initialization pattern with the new period and
    /// queue size, and resume.
    PaperDynamic,
}

impl Mode {
    /// Every mode, for help texts.
    pub(crate) const ALL: [Mode; 2] = [Mode::PaperStatic, Mode::PaperDynamic];

    /// The name used on the command line and in reports.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Mode::PaperStatic => "paper-static",
            Mode::PaperDynamic => "paper-dynamic",
        }
    }
}

impl From<Mode> for wire::ModeCode {
    fn from(mode: Mode) -> wire::ModeCode {
        match mode {
            Mode::PaperStatic => wire::ModeCode::PaperStatic,
            Mode::PaperDynamic => wire::ModeCode::PaperDynamic,
        }
    }
}

/// The mode of a Hello's code; a code this build does not know is given
/// back as the error.
impl TryFrom<wire::ModeCode> for Mode {
    type Error = wire::ModeCode;
    fn try_from(code: wire::ModeCode) -> Result<Mode, wire::ModeCode> {
        match code {
            wire::ModeCode::PaperStatic => Ok(Mode::PaperStatic),
            wire::ModeCode::PaperDynamic => Ok(Mode::PaperDynamic),
            other => Err(other),
        }
    }
}

impl fmt::Display for Mode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A name that is not a known [`Mode`] or
/// [`Underflow`](crate::endpoint::Underflow) policy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct UnknownName {
    /// What kind of name was expected.
    pub(crate) what: &'static str,
    /// The valid names.
    pub(crate) valid: &'static str,
}

impl fmt::Display for UnknownName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "unknown {}; valid: {}", self.what, self.valid)
    }
}

impl core::error::Error for UnknownName {}

impl FromStr for Mode {
    type Err = UnknownName;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Mode::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or(UnknownName {
                what: "mode",
                valid: "paper-static, paper-dynamic",
            })
    }
}

/// How the delay is regulated: the one name a user gives, the same in Rust,
/// on the command line (`--regulation`), in Python (`regulation=`) and in
/// JSON reports (`"regulation"`).
///
/// A [`Regulation`] sets the two parts of a [`Config`](crate::Config) that
/// decide the delay: the [`Mode`] both peers agree on at the handshake, and
/// this side's [`Playout`]. Every regulation but the paper's dynamic one runs
/// the static handshake; the target-delay playouts do not resize the queues,
/// they move the delay themselves.
///
/// ```
/// use ndr_core::Regulation;
/// use ndr_core::{Mode, Playout};
///
/// let r: Regulation = "paper-dynamic".parse().unwrap();
/// assert_eq!((r.mode(), r.playout()), (Mode::PaperDynamic, Playout::Fifo));
/// assert_eq!("adaptive".parse::<Regulation>().unwrap(), Regulation::ADAPTIVE);
/// assert_eq!(Regulation::ADAPTIVE.to_string(), "adaptive");
/// ```
///
/// How a side regulates the delay, by the name users give it.
///
/// Its names: `adaptive[:PERCENT[:QUANTUM_MS]]` (ndr's default),
/// `paper-static`, `paper-dynamic`, `ramjee-1`, `ramjee-4`, `neteq`,
/// `fixed[:MS]` and `constant:MS`; [`Playout`] documents each target-delay
/// policy and its values.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Regulation {
    /// The paper's static NDR: a FIFO sized once by the initialization
    /// pattern, one release per tick.
    PaperStatic,
    /// The paper's dynamic NDR: the FIFO resized (with a pause) when the
    /// network predictor's forecast leaves its band.
    PaperDynamic,
    /// A target-delay playout over the static handshake. `Target(Playout::Fifo)`
    /// is [`Regulation::PaperStatic`] under another spelling: it is named and
    /// behaves as that.
    Target(Playout),
}

impl Default for Regulation {
    /// [`Regulation::ADAPTIVE`], as [`Config::new`](crate::Config::new).
    fn default() -> Self {
        Regulation::ADAPTIVE
    }
}

impl Regulation {
    /// The adaptive playout at its default late rate (0.1 %) and quantum.
    pub const ADAPTIVE: Regulation = Regulation::Target(Playout::ADAPTIVE);

    /// The regulation that sets `mode` and `playout`, `None` for the pairing
    /// no regulation names: the dynamic mode's resizes under a target-delay
    /// playout (a [`Config`](crate::Config) can still be given it field by
    /// field).
    #[must_use]
    pub(crate) const fn of(mode: Mode, playout: Playout) -> Option<Regulation> {
        match (mode, playout) {
            (Mode::PaperStatic, Playout::Fifo) => Some(Regulation::PaperStatic),
            (Mode::PaperDynamic, Playout::Fifo) => Some(Regulation::PaperDynamic),
            (Mode::PaperStatic, p) => Some(Regulation::Target(p)),
            (Mode::PaperDynamic, _) => None,
        }
    }

    /// How reports name `mode` with `playout`: the regulation's name, or
    /// `MODE with PLAYOUT` for the pairing no regulation names.
    #[must_use]
    pub fn name_of(mode: Mode, playout: Playout) -> impl fmt::Display {
        PairingName { mode, playout }
    }

    /// The mode it states in the Hello.
    #[must_use]
    pub const fn mode(self) -> Mode {
        match self {
            Regulation::PaperDynamic => Mode::PaperDynamic,
            Regulation::PaperStatic | Regulation::Target(_) => Mode::PaperStatic,
        }
    }

    /// When its regulator releases each sample.
    #[must_use]
    pub const fn playout(self) -> Playout {
        match self {
            Regulation::PaperStatic | Regulation::PaperDynamic => Playout::Fifo,
            Regulation::Target(p) => p,
        }
    }

    /// Whether it is one of the paper's FIFO regulations.
    #[must_use]
    pub const fn is_paper(self) -> bool {
        matches!(self.playout(), Playout::Fifo)
    }

    /// The names it takes, for messages and help texts, from the playout
    /// registry: `default` first, marked as the default, then the paper's
    /// two (its FIFO sized once or resized) and the other policies in the
    /// registry's order (`adaptive[:PERCENT[:QUANTUM_MS]] (the default),
    /// paper-static, paper-dynamic, ramjee-1, …`); with no default, all in
    /// the registry's order, none marked.
    #[must_use]
    pub fn names(default: Option<Regulation>) -> impl fmt::Display {
        RegulationNames { default }
    }

    /// Every regulation the registry names by a bare name, in the order of
    /// [`Regulation::names`]'s list: the paper's two, then
    /// each target policy at its defaults (one that needs a value, such as
    /// `constant:MS`, is left out). What `ndr compare` runs by default.
    pub fn every() -> impl Iterator<Item = Regulation> {
        [Regulation::PaperStatic, Regulation::PaperDynamic]
            .into_iter()
            .chain(
                Playout::registered()
                    .iter()
                    .filter_map(|s| s.name.parse::<Regulation>().ok()),
            )
    }
}

impl fmt::Display for Regulation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match Regulation::of(self.mode(), self.playout()) {
            Some(Regulation::Target(p)) => write!(f, "{p}"),
            _ => f.write_str(self.mode().name()),
        }
    }
}

/// Displays a mode and playout as reports name them
/// ([`Regulation::name_of`]).
#[derive(Clone, Copy, Debug)]
struct PairingName {
    mode: Mode,
    playout: Playout,
}

impl fmt::Display for PairingName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match Regulation::of(self.mode, self.playout) {
            Some(r) => write!(f, "{r}"),
            None => write!(f, "{} with {}", self.mode, self.playout),
        }
    }
}

/// A name that is not a [`Regulation`], or a known one with a value out of
/// its range.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum UnknownRegulation {
    /// No regulation has this name.
    Name,
    /// `fifo` names the paper's queue but not how it is sized.
    Fifo,
    /// A target-delay playout's value is out of its range (the playout's
    /// message says which).
    Value(UnknownPlayout),
}

/// The names [`Regulation`] takes ([`Regulation::names`]).
#[derive(Clone, Copy, Debug)]
struct RegulationNames {
    default: Option<Regulation>,
}

impl RegulationNames {
    /// Each name's syntax and whether it names the default, in the
    /// registry's order (the FIFO's entry is the paper's two).
    fn each(self) -> impl Iterator<Item = (&'static str, bool)> {
        let fifo = Playout::Fifo.syntax();
        let default = self.default;
        Playout::registered().iter().flat_map(move |s| {
            let paper = Some(s) == fifo;
            let one = if paper {
                Mode::PaperStatic.name()
            } else {
                s.syntax
            };
            let named = |r: Regulation| match r {
                Regulation::PaperStatic => paper && one == Mode::PaperStatic.name(),
                Regulation::PaperDynamic => false,
                Regulation::Target(p) => !paper && p.syntax() == Some(s),
            };
            let first = (one, default.is_some_and(named));
            let second = paper.then_some((
                Mode::PaperDynamic.name(),
                default == Some(Regulation::PaperDynamic),
            ));
            core::iter::once(first).chain(second)
        })
    }
}

impl fmt::Display for RegulationNames {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut first = true;
        for (name, _) in self.each().filter(|&(_, d)| d) {
            write!(f, "{name} (the default)")?;
            first = false;
        }
        for (name, _) in self.each().filter(|&(_, d)| !d) {
            if !first {
                f.write_str(", ")?;
            }
            f.write_str(name)?;
            first = false;
        }
        Ok(())
    }
}

impl fmt::Display for UnknownRegulation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            UnknownRegulation::Name => {
                write!(
                    f,
                    "unknown regulation; valid: {}",
                    Regulation::names(Some(Regulation::ADAPTIVE))
                )
            }
            UnknownRegulation::Fifo => f.write_str(
                "`fifo` is the paper's queue: say how it is sized, paper-static (once, \
                 at the handshake) or paper-dynamic (again when the network changes)",
            ),
            UnknownRegulation::Value(e) => write!(f, "{e}"),
        }
    }
}

impl core::error::Error for UnknownRegulation {}

impl FromStr for Regulation {
    type Err = UnknownRegulation;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim() {
            "paper-static" => Ok(Regulation::PaperStatic),
            "paper-dynamic" => Ok(Regulation::PaperDynamic),
            "fifo" => Err(UnknownRegulation::Fifo),
            other => match other.parse::<Playout>() {
                Ok(p) => Ok(Regulation::Target(p)),
                Err(e) if e.is_unknown_name() => Err(UnknownRegulation::Name),
                Err(e) => Err(UnknownRegulation::Value(e)),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use std::string::ToString;

    use super::*;
    use crate::time::Duration;

    #[test]
    fn every_name_reads_back_as_itself() {
        for name in [
            "adaptive",
            "adaptive:1",
            "adaptive:0.1:10",
            "paper-static",
            "paper-dynamic",
            "ramjee-1",
            "ramjee-4",
            "neteq",
            "fixed:200",
            "constant:120",
        ] {
            let r: Regulation = name.parse().unwrap();
            assert_eq!(r.to_string(), name);
            assert_eq!(r.to_string().parse::<Regulation>(), Ok(r));
        }
    }

    #[test]
    fn a_regulation_sets_the_mode_and_the_playout() {
        let cases = [
            (Regulation::PaperStatic, Mode::PaperStatic, Playout::Fifo),
            (Regulation::PaperDynamic, Mode::PaperDynamic, Playout::Fifo),
            (Regulation::ADAPTIVE, Mode::PaperStatic, Playout::ADAPTIVE),
            (
                Regulation::Target(Playout::NetEq),
                Mode::PaperStatic,
                Playout::NetEq,
            ),
        ];
        for (r, mode, playout) in cases {
            assert_eq!((r.mode(), r.playout()), (mode, playout), "{r}");
            assert_eq!(Regulation::of(mode, playout), Some(r));
        }
        assert_eq!(Regulation::of(Mode::PaperDynamic, Playout::ADAPTIVE), None);
        let unnamed = Regulation::name_of(Mode::PaperDynamic, Playout::ADAPTIVE);
        assert_eq!(unnamed.to_string(), "paper-dynamic with adaptive");
        let named = Regulation::name_of(Mode::PaperStatic, Playout::NetEq);
        assert_eq!(named.to_string(), "neteq");
        assert_eq!(Regulation::default(), Regulation::ADAPTIVE);
    }

    #[test]
    fn the_fifo_as_a_target_is_the_static_paper_regulation() {
        let r = Regulation::Target(Playout::Fifo);
        assert_eq!(r.to_string(), "paper-static");
        assert_eq!((r.mode(), r.playout()), (Mode::PaperStatic, Playout::Fifo));
        assert!(r.is_paper() && !Regulation::ADAPTIVE.is_paper());
    }

    #[test]
    fn the_names_come_from_the_registry() {
        assert_eq!(
            Regulation::names(Some(Regulation::ADAPTIVE)).to_string(),
            "adaptive[:PERCENT[:QUANTUM_MS]] (the default), paper-static, paper-dynamic, \
             ramjee-1, ramjee-4, neteq, fixed[:MS], constant:MS"
        );
        assert_eq!(
            Regulation::names(Some(Regulation::PaperStatic)).to_string(),
            "paper-static (the default), paper-dynamic, ramjee-1, ramjee-4, neteq, \
             fixed[:MS], constant:MS, adaptive[:PERCENT[:QUANTUM_MS]]"
        );
        assert_eq!(
            Regulation::names(None).to_string(),
            "paper-static, paper-dynamic, ramjee-1, ramjee-4, neteq, fixed[:MS], constant:MS, \
             adaptive[:PERCENT[:QUANTUM_MS]]"
        );
        let every: std::vec::Vec<_> = Regulation::every().map(|r| r.to_string()).collect();
        assert_eq!(
            every,
            [
                "paper-static",
                "paper-dynamic",
                "ramjee-1",
                "ramjee-4",
                "neteq",
                "fixed:200",
                "adaptive"
            ]
        );
    }

    #[test]
    fn a_wrong_name_says_what_is_valid() {
        let unknown = "lifo".parse::<Regulation>().unwrap_err();
        assert_eq!(unknown, UnknownRegulation::Name);
        assert!(unknown.to_string().contains("paper-dynamic"));
        assert!(unknown.to_string().contains("adaptive[:PERCENT"));
        let fifo = "fifo".parse::<Regulation>().unwrap_err();
        assert!(fifo.to_string().contains("paper-static"), "{fifo}");
        let range = "adaptive:150".parse::<Regulation>().unwrap_err();
        assert!(matches!(range, UnknownRegulation::Value(_)));
        assert!(range.to_string().contains("0 < PERCENT < 100"), "{range}");
        assert_eq!(
            "constant:7.5".parse::<Regulation>(),
            Ok(Regulation::Target(Playout::Constant {
                delay: Duration::from_micros(7500)
            }))
        );
    }
}
