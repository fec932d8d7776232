//! The operator's command signal in the simulator.
//!
//! A [`Signal`] gives the command of each axis at each time. Axes get
//! distinct phases (the golden angle apart, so no two of them ever line up)
//! so that a multi-axis run does not send the same number on every channel.
//!
//! The text form, for the command line, round-trips through
//! [`Display`](core::fmt::Display) and [`FromStr`]:
//!
//! ```text
//! sine                              amplitude 1, 0.2 Hz, offset 0 (the default)
//! sine:amp=0.5,freq=1,offset=0.1
//! steps                             square wave 0 → 1, period 4 s
//! steps:low=-1,high=1,period=2
//! constant:0.5
//! ```

use core::f64::consts::TAU;
use core::fmt;
use core::str::FromStr;
use std::string::String;

use super::delay::snippet;

/// The golden angle as a fraction of a turn, `2 − φ`: successive axes are
/// shifted by it, which never brings two axes back in phase.
const AXIS_PHASE_TURNS: f64 = 0.381_966_011_250_105_1;

/// The operator's command: one value per axis at each time.
#[derive(Clone, Debug, PartialEq)]
pub enum Signal {
    /// `offset + amplitude · sin(2π·freq_hz·t + phase(axis))`.
    Sine {
        /// Peak deviation from the offset.
        amplitude: f64,
        /// Frequency, Hz (≥ 0).
        freq_hz: f64,
        /// Mean value.
        offset: f64,
    },
    /// A square wave: `high` for the first half of each period, `low` for
    /// the second; axis `i` is shifted by a fraction of the period.
    Steps {
        /// Value of the low half.
        low: f64,
        /// Value of the high half.
        high: f64,
        /// Period, s (> 0).
        period_s: f64,
    },
    /// The same value at all times on all axes.
    Constant(f64),
}

impl Default for Signal {
    /// A 0.2 Hz sine of amplitude 1: slow enough for the paper's 200 ms period.
    fn default() -> Self {
        Signal::Sine {
            amplitude: 1.0,
            freq_hz: 0.2,
            offset: 0.0,
        }
    }
}

impl Signal {
    /// The command of `axis` at time `t_s` (seconds from the start of the
    /// run). A non-finite time counts as 0; parameters that [`FromStr`] would
    /// refuse (a non-positive period, say) give a finite value, not a panic.
    #[must_use]
    pub fn value(&self, t_s: f64, axis: usize) -> f64 {
        let t = if t_s.is_finite() { t_s } else { 0.0 };
        // Only the fractional part matters; `rem_euclid` keeps it exact for any axis.
        let shift = (axis as f64 * AXIS_PHASE_TURNS).rem_euclid(1.0);
        match *self {
            Signal::Sine {
                amplitude,
                freq_hz,
                offset,
            } => {
                // Reduce the phase in turns first: sin of a huge argument loses precision.
                let turns = (freq_hz * t + shift).rem_euclid(1.0);
                offset + amplitude * libm::sin(TAU * turns)
            }
            Signal::Steps {
                low,
                high,
                period_s,
            } => {
                if !(period_s.is_finite() && period_s > 0.0) {
                    return low;
                }
                let turns = (t / period_s + shift).rem_euclid(1.0);
                if turns < 0.5 { high } else { low }
            }
            Signal::Constant(v) => v,
        }
    }

    /// The kind's name: `sine`, `steps` or `constant`.
    #[must_use]
    pub fn kind(&self) -> &'static str {
        match self {
            Signal::Sine { .. } => "sine",
            Signal::Steps { .. } => "steps",
            Signal::Constant(_) => "constant",
        }
    }
}

impl fmt::Display for Signal {
    /// The form [`FromStr`] reads, every parameter written out.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Signal::Sine {
                amplitude,
                freq_hz,
                offset,
            } => write!(f, "sine:amp={amplitude},freq={freq_hz},offset={offset}"),
            Signal::Steps {
                low,
                high,
                period_s,
            } => write!(f, "steps:low={low},high={high},period={period_s}"),
            Signal::Constant(v) => write!(f, "constant:{v}"),
        }
    }
}

/// Why a signal description was refused.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum SignalError {
    /// Not `sine`, `steps` or `constant`.
    UnknownKind(String),
    /// A parameter the kind does not have.
    UnknownKey {
        /// The kind.
        kind: &'static str,
        /// The parameter given.
        key: String,
    },
    /// A parameter without `=`.
    MissingValue {
        /// The kind.
        kind: &'static str,
        /// The text given.
        item: String,
    },
    /// The same parameter twice.
    Duplicate {
        /// The parameter.
        key: &'static str,
    },
    /// A value that is not a finite number.
    BadNumber {
        /// The parameter.
        key: &'static str,
        /// The text given.
        text: String,
    },
    /// A frequency below zero or a period not above zero.
    OutOfRange {
        /// The parameter.
        key: &'static str,
        /// What it must be.
        rule: &'static str,
    },
}

impl fmt::Display for SignalError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        const FORMS: &str =
            "sine[:amp=A,freq=HZ,offset=O], steps[:low=L,high=H,period=S] or constant:V";
        match self {
            SignalError::UnknownKind(k) => {
                write!(f, "unknown signal `{k}`: expected {FORMS}")
            }
            SignalError::UnknownKey { kind, key } => {
                let keys = match *kind {
                    "sine" => "amp, freq, offset",
                    "steps" => "low, high, period",
                    _ => "none (write constant:V)",
                };
                write!(
                    f,
                    "`{key}` is not a parameter of {kind}; its parameters: {keys}"
                )
            }
            SignalError::MissingValue { kind, item } => {
                write!(
                    f,
                    "{kind} parameter `{item}` has no value: write KEY=VALUE, e.g. {FORMS}"
                )
            }
            SignalError::Duplicate { key } => write!(f, "parameter `{key}` is given twice"),
            SignalError::BadNumber { key, text } => {
                write!(f, "{key} = `{text}` is not a finite number")
            }
            SignalError::OutOfRange { key, rule } => write!(f, "{key} must be {rule}"),
        }
    }
}

impl std::error::Error for SignalError {}

impl FromStr for Signal {
    type Err = SignalError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let s = s.trim();
        let (kind, params) = match s.split_once(':') {
            Some((k, p)) => (k.trim(), Some(p.trim())),
            None => (s, None),
        };
        match kind.to_ascii_lowercase().as_str() {
            "sine" | "sin" => {
                let mut v = [Some(1.0), Some(0.2), Some(0.0)];
                parse_params(
                    "sine",
                    params,
                    &[&["amp", "amplitude"], &["freq", "freq_hz"], &["offset"]],
                    &mut v,
                )?;
                let [amplitude, freq_hz, offset] = v.map(|x| x.unwrap_or(0.0));
                if freq_hz < 0.0 {
                    return Err(SignalError::OutOfRange {
                        key: "freq",
                        rule: "zero or more (Hz)",
                    });
                }
                Ok(Signal::Sine {
                    amplitude,
                    freq_hz,
                    offset,
                })
            }
            "steps" | "square" => {
                let mut v = [Some(0.0), Some(1.0), Some(4.0)];
                parse_params(
                    "steps",
                    params,
                    &[&["low"], &["high"], &["period", "period_s"]],
                    &mut v,
                )?;
                let [low, high, period_s] = v.map(|x| x.unwrap_or(0.0));
                if period_s <= 0.0 {
                    return Err(SignalError::OutOfRange {
                        key: "period",
                        rule: "above zero (seconds)",
                    });
                }
                Ok(Signal::Steps {
                    low,
                    high,
                    period_s,
                })
            }
            "constant" | "const" => match params {
                None | Some("") => Ok(Signal::Constant(0.0)),
                Some(p) => {
                    let text = p.strip_prefix("value=").unwrap_or(p).trim();
                    Ok(Signal::Constant(number("value", text)?))
                }
            },
            _ => Err(SignalError::UnknownKind(snippet(kind))),
        }
    }
}

/// Fills `values` from `key=value` pairs; `names[i]` lists the spellings of
/// parameter `i`, the first being canonical.
fn parse_params(
    kind: &'static str,
    params: Option<&str>,
    names: &[&[&'static str]],
    values: &mut [Option<f64>],
) -> Result<(), SignalError> {
    let Some(params) = params.filter(|p| !p.is_empty()) else {
        return Ok(());
    };
    let mut seen = [false; 3];
    for item in params.split(',') {
        let item = item.trim();
        let Some((key, text)) = item.split_once('=') else {
            return Err(SignalError::MissingValue {
                kind,
                item: snippet(item),
            });
        };
        let key = key.trim().to_ascii_lowercase();
        let Some(i) = names.iter().position(|n| n.contains(&key.as_str())) else {
            return Err(SignalError::UnknownKey {
                kind,
                key: snippet(&key),
            });
        };
        let canonical = names.get(i).and_then(|n| n.first()).copied().unwrap_or("?");
        if seen.get(i).copied().unwrap_or(false) {
            return Err(SignalError::Duplicate { key: canonical });
        }
        if let Some(s) = seen.get_mut(i) {
            *s = true;
        }
        if let Some(slot) = values.get_mut(i) {
            *slot = Some(number(canonical, text.trim())?);
        }
    }
    Ok(())
}

fn number(key: &'static str, text: &str) -> Result<f64, SignalError> {
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(SignalError::BadNumber {
            key,
            text: snippet(text),
        }),
    }
}
