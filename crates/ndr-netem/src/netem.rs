//! iproute2 netem distribution tables (`*.dist`) and the kernel's way of
//! sampling them.
//!
//! A table holds signed integers, the quantiles of a distribution of zero mean
//! and unit standard deviation scaled by [`NETEM_DIST_SCALE`]: entry `t` means
//! `t / 8192` standard deviations. `tc qdisc ... netem delay MU SIGMA
//! distribution NAME` draws an entry uniformly and delays the packet by
//! `MU + SIGMA·t/8192`, computed exactly as the kernel's `tabledist()` does.

use core::fmt;
use std::path::{Path, PathBuf};
use std::string::String;
use std::vec::Vec;

use ndr_core::time::Duration;
use rand::Rng;

use super::{ReadError, read_capped, snippet};

/// The scale of table entries: `8192` means one standard deviation.
pub const NETEM_DIST_SCALE: i64 = 8192;
/// Most entries a table may hold (iproute2's `MAX_DIST`, 16 Ki).
pub const MAX_DIST_ENTRIES: usize = 16 * 1024;
/// Largest table file read, in bytes: iproute2's tables are about 23 kB, and
/// 16 Ki entries of 6 characters with separators fit in 128 KiB.
pub const MAX_DIST_FILE_BYTES: u64 = 1024 * 1024;

/// A netem distribution table: between 1 and [`MAX_DIST_ENTRIES`] entries,
/// each in the `i16` range.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DistTable {
    entries: Vec<i16>,
}

/// Why a distribution table was refused.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum DistError {
    /// The text holds no entry at all.
    Empty,
    /// A token is not a decimal integer.
    NotAnInteger {
        /// 1-based line number.
        line: usize,
        /// The token (shortened if long).
        token: String,
    },
    /// An integer outside `-32768..=32767`, which the kernel stores in 16 bits.
    OutOfRange {
        /// 1-based line number.
        line: usize,
        /// The token (shortened if long).
        token: String,
    },
    /// More than [`MAX_DIST_ENTRIES`] entries.
    TooManyEntries {
        /// The line where the limit was passed.
        line: usize,
    },
    /// The file is larger than [`MAX_DIST_FILE_BYTES`].
    FileTooLarge {
        /// The file.
        path: PathBuf,
        /// The limit, in bytes.
        max: u64,
    },
    /// The file could not be read (missing, unreadable, not UTF-8).
    Io {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        message: String,
    },
}

impl fmt::Display for DistError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DistError::Empty => f.write_str(
                "the distribution table has no entries: expect whitespace-separated integers \
                 such as iproute2's normal.dist (4096 entries)",
            ),
            DistError::NotAnInteger { line, token } => write!(
                f,
                "line {line}: `{token}` is not an integer; a netem table holds decimal integers \
                 (one standard deviation = {NETEM_DIST_SCALE}) and `#` comment lines"
            ),
            DistError::OutOfRange { line, token } => write!(
                f,
                "line {line}: {token} is outside the 16-bit range -32768..=32767 that netem \
                 tables use; rescale the table so one standard deviation is {NETEM_DIST_SCALE}"
            ),
            DistError::TooManyEntries { line } => write!(
                f,
                "line {line}: more than {MAX_DIST_ENTRIES} entries, the most iproute2 accepts; \
                 resample the table"
            ),
            DistError::FileTooLarge { path, max } => write!(
                f,
                "{} is larger than {max} bytes, too large for a netem table \
                 (iproute2's are about 23 kB)",
                path.display()
            ),
            DistError::Io { path, message } => {
                write!(f, "cannot read {}: {message}", path.display())
            }
        }
    }
}

impl std::error::Error for DistError {}

impl DistTable {
    /// Parses the text of a `*.dist` file: whitespace-separated decimal
    /// integers (optional sign); lines whose first non-blank character is `#`
    /// are comments, as in iproute2.
    ///
    /// # Errors
    ///
    /// [`DistError`] naming the line of the first bad token, or
    /// [`DistError::Empty`].
    pub fn parse(text: &str) -> Result<DistTable, DistError> {
        let mut entries = Vec::new();
        for (index, raw) in text.lines().enumerate() {
            let line = index + 1;
            let content = raw.trim();
            if content.starts_with('#') {
                continue;
            }
            for token in content.split_whitespace() {
                let value = parse_entry(token).map_err(|out_of_range| {
                    let token = snippet(token);
                    if out_of_range {
                        DistError::OutOfRange { line, token }
                    } else {
                        DistError::NotAnInteger { line, token }
                    }
                })?;
                if entries.len() == MAX_DIST_ENTRIES {
                    return Err(DistError::TooManyEntries { line });
                }
                entries.push(value);
            }
        }
        DistTable::from_entries(entries)
    }

    /// Reads and parses a `*.dist` file (at most [`MAX_DIST_FILE_BYTES`]).
    ///
    /// # Errors
    ///
    /// [`DistError::Io`] or [`DistError::FileTooLarge`] if the file cannot be
    /// read, else what [`DistTable::parse`] returns.
    pub fn from_path(path: impl AsRef<Path>) -> Result<DistTable, DistError> {
        let path = path.as_ref();
        let text = read_capped(path, MAX_DIST_FILE_BYTES).map_err(|e| match e {
            ReadError::TooLarge => DistError::FileTooLarge {
                path: path.to_path_buf(),
                max: MAX_DIST_FILE_BYTES,
            },
            ReadError::Io(message) => DistError::Io {
                path: path.to_path_buf(),
                message,
            },
        })?;
        DistTable::parse(&text)
    }

    /// A table from its entries.
    ///
    /// # Errors
    ///
    /// [`DistError::Empty`] or [`DistError::TooManyEntries`] (line 0).
    pub fn from_entries(entries: Vec<i16>) -> Result<DistTable, DistError> {
        if entries.is_empty() {
            return Err(DistError::Empty);
        }
        if entries.len() > MAX_DIST_ENTRIES {
            return Err(DistError::TooManyEntries { line: 0 });
        }
        Ok(DistTable { entries })
    }

    /// The entries, in file order.
    #[must_use]
    pub fn entries(&self) -> &[i16] {
        &self.entries
    }

    /// Number of entries (never zero).
    #[must_use]
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Always `false`: an empty table is refused.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Mean and standard deviation of the entries, in units of one standard
    /// deviation (entry / 8192): about `(0, 1)` for a well-formed table.
    #[must_use]
    pub fn moments(&self) -> (f64, f64) {
        let n = self.entries.len() as f64;
        let scale = NETEM_DIST_SCALE as f64;
        let mean = self.entries.iter().map(|&t| f64::from(t)).sum::<f64>() / n / scale;
        let var = self
            .entries
            .iter()
            .map(|&t| {
                let d = f64::from(t) / scale - mean;
                d * d
            })
            .sum::<f64>()
            / n;
        (mean, var.sqrt())
    }

    /// The value of entry `t` for `mu` and `sigma` in nanoseconds, rounded
    /// like the kernel's `tabledist()`:
    /// `(sigma % 8192)·t / 8192` rounded half away from zero, plus
    /// `(sigma / 8192)·t + mu`. Clamped to `[0, u64::MAX]` nanoseconds.
    #[must_use]
    pub fn scale_entry(t: i16, mu: Duration, sigma: Duration) -> Duration {
        let scale = i128::from(NETEM_DIST_SCALE);
        let t = i128::from(t);
        let sigma = i128::from(sigma.as_nanos());
        let mut x = (sigma % scale) * t;
        x += if x >= 0 { scale / 2 } else { -scale / 2 };
        let nanos = x / scale + (sigma / scale) * t + i128::from(mu.as_nanos());
        Duration::from_nanos(u64::try_from(nanos.max(0)).unwrap_or(u64::MAX))
    }

    /// One delay drawn as netem does: a uniformly chosen entry, scaled by
    /// [`DistTable::scale_entry`]; negative values give zero.
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R, mu: Duration, sigma: Duration) -> Duration {
        use rand::RngExt;
        let i = rng.random_range(0..self.entries.len());
        let t = self.entries.get(i).copied().unwrap_or(0);
        DistTable::scale_entry(t, mu, sigma)
    }
}

/// `Err(true)` for an integer out of the `i16` range, `Err(false)` for a
/// token that is not an integer.
fn parse_entry(token: &str) -> Result<i16, bool> {
    let digits = token.strip_prefix(['+', '-']).unwrap_or(token);
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return Err(false);
    }
    let digits_only = digits.trim_start_matches('0');
    // Anything longer than 6 digits cannot fit; spare i128 parsing of huge tokens.
    if digits_only.len() > 6 {
        return Err(true);
    }
    let value: i64 = token.parse().map_err(|_| false)?;
    i16::try_from(value).map_err(|_| true)
}
