//! Delay traces (DESIGN §6): a CSV file of one-way delays over time, read by
//! the simulator and by the relay.
//!
//! ```text
//! t_s,fwd_ms,bwd_ms
//! 0,30.5,31
//! 1.5,120,45
//! ```
//!
//! The delay of a frame sent at time `t` in a direction is that of the last
//! row with `t_s ≤ t`; before the first row, the first row's. Blank lines and
//! lines starting with `#` are skipped; spaces around fields and CRLF line
//! ends are tolerated. Times must not decrease (equal times are allowed: the
//! later row wins).

use core::fmt;
use std::path::{Path, PathBuf};
use std::string::String;
use std::vec::Vec;

use ndr_core::time::{Duration, Instant};

use super::{Direction, Millis, ReadError, read_capped, snippet};

/// The header a trace must start with.
pub const TRACE_HEADER: &str = "t_s,fwd_ms,bwd_ms";
/// Most rows a trace may hold (10 million: 23 days at 5 rows a second).
pub const MAX_TRACE_ROWS: usize = 10_000_000;
/// Largest trace file read, in bytes.
pub const MAX_TRACE_FILE_BYTES: u64 = 512 * 1024 * 1024;
/// Largest time accepted, in seconds (about 31.7 years).
pub const MAX_TRACE_TIME_S: f64 = 1e9;
/// Largest one-way delay accepted, in milliseconds (one day).
pub const MAX_TRACE_DELAY_MS: f64 = 86_400_000.0;

/// One row of a trace: from `at` on, frames take `fwd` and `bwd`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TraceRow {
    /// When the row starts to apply.
    pub at: Instant,
    /// One-way delay base → remote.
    pub fwd: Duration,
    /// One-way delay remote → base.
    pub bwd: Duration,
}

/// A delay trace: at least one row, times non-decreasing.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Trace {
    rows: Vec<TraceRow>,
    /// A replayed recording's: when its link sent its first command.
    anchor: Option<Instant>,
    /// A replayed recording's probes, each way: their sequence numbers
    /// (ascending) and delays.
    probes: [Vec<(u64, Duration)>; 2],
    /// A replayed recording's samples never released, each way: the spans
    /// (ascending, disjoint) in which a datagram sent is lost.
    lost: [Vec<(Instant, Instant)>; 2],
}

/// What a replayed recording says of a probe ([`Trace::probe`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RecordedProbe {
    /// It arrived after this delay.
    Delayed(Duration),
    /// It never arrived (or never went out: a datagram before its path
    /// was open): numbered below the last one that arrived.
    Lost,
    /// The recording does not say: numbered past its probes (the replay's
    /// set-up runs longer than the recorded one), or it holds none.
    Unrecorded,
}

/// Which column of a trace row.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Column {
    /// `t_s`.
    Time,
    /// `fwd_ms`.
    Forward,
    /// `bwd_ms`.
    Backward,
}

impl Column {
    /// The column's name in the header.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Column::Time => "t_s",
            Column::Forward => "fwd_ms",
            Column::Backward => "bwd_ms",
        }
    }
}

/// Why a trace was refused. Line numbers are 1-based and count every line
/// of the file, the header included.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum TraceError {
    /// No header: the text is empty or holds only comments and blank lines.
    Empty,
    /// The first line is not [`TRACE_HEADER`].
    BadHeader {
        /// 1-based line number.
        line: usize,
        /// What the line holds (shortened if long).
        found: String,
    },
    /// A header but no row.
    NoRows,
    /// A row without exactly three fields.
    ColumnCount {
        /// 1-based line number.
        line: usize,
        /// Fields found.
        found: usize,
    },
    /// A field that is not a number.
    NotANumber {
        /// 1-based line number.
        line: usize,
        /// The column.
        column: Column,
        /// The field (shortened if long).
        text: String,
    },
    /// A NaN or infinite value.
    NotFinite {
        /// 1-based line number.
        line: usize,
        /// The column.
        column: Column,
    },
    /// A negative time or delay.
    Negative {
        /// 1-based line number.
        line: usize,
        /// The column.
        column: Column,
        /// The value.
        value: f64,
    },
    /// A time above [`MAX_TRACE_TIME_S`] or a delay above [`MAX_TRACE_DELAY_MS`].
    TooLarge {
        /// 1-based line number.
        line: usize,
        /// The column.
        column: Column,
        /// The value.
        value: f64,
    },
    /// A time earlier than the previous row's.
    Unsorted {
        /// 1-based line number.
        line: usize,
        /// This row's time, s.
        t_s: f64,
        /// The previous row's time, s.
        previous_s: f64,
    },
    /// More than [`MAX_TRACE_ROWS`] rows.
    TooManyRows {
        /// The line where the limit was passed.
        line: usize,
    },
    /// The file is larger than [`MAX_TRACE_FILE_BYTES`].
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

impl fmt::Display for TraceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TraceError::Empty => write!(
                f,
                "the trace is empty: line 1 must be the header `{TRACE_HEADER}`, \
                 followed by one row per delay change"
            ),
            TraceError::BadHeader { line, found } => write!(
                f,
                "line {line}: expected the header `{TRACE_HEADER}`, found `{found}`"
            ),
            TraceError::NoRows => write!(
                f,
                "the trace has a header but no rows: add at least one `t_s,fwd_ms,bwd_ms` row \
                 such as `0,30,30`"
            ),
            TraceError::ColumnCount { line, found } => write!(
                f,
                "line {line}: expected 3 comma-separated fields (t_s,fwd_ms,bwd_ms), found {found}"
            ),
            TraceError::NotANumber { line, column, text } => {
                write!(f, "line {line}: {} `{text}` is not a number", column.name())
            }
            TraceError::NotFinite { line, column } => write!(
                f,
                "line {line}: {} must be a finite number, not NaN or infinity",
                column.name()
            ),
            TraceError::Negative {
                line,
                column,
                value,
            } => write!(
                f,
                "line {line}: {} is {value}; times and delays cannot be negative",
                column.name()
            ),
            TraceError::TooLarge {
                line,
                column,
                value,
            } => {
                let max = if *column == Column::Time {
                    MAX_TRACE_TIME_S
                } else {
                    MAX_TRACE_DELAY_MS
                };
                write!(
                    f,
                    "line {line}: {} is {value}, above the limit of {max}; check the units \
                     (seconds for t_s, milliseconds for delays)",
                    column.name()
                )
            }
            TraceError::Unsorted {
                line,
                t_s,
                previous_s,
            } => write!(
                f,
                "line {line}: t_s {t_s} is earlier than the previous row's {previous_s}; \
                 sort the rows by time"
            ),
            TraceError::TooManyRows { line } => write!(
                f,
                "line {line}: more than {MAX_TRACE_ROWS} rows; keep only the rows where a delay \
                 changes, or split the trace"
            ),
            TraceError::FileTooLarge { path, max } => write!(
                f,
                "{} is larger than {max} bytes, the most a trace may take",
                path.display()
            ),
            TraceError::Io { path, message } => {
                write!(f, "cannot read {}: {message}", path.display())
            }
        }
    }
}

impl std::error::Error for TraceError {}

impl Trace {
    /// Parses a trace from CSV text.
    ///
    /// # Errors
    ///
    /// The first problem found, as a [`TraceError`] naming its line.
    pub fn parse(text: &str) -> Result<Trace, TraceError> {
        let mut lines = text
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l.trim()))
            .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
        let (line, header) = lines.next().ok_or(TraceError::Empty)?;
        let fields: Vec<&str> = header.split(',').map(str::trim).collect();
        if fields != ["t_s", "fwd_ms", "bwd_ms"] {
            return Err(TraceError::BadHeader {
                line,
                found: snippet(header),
            });
        }
        let mut rows: Vec<TraceRow> = Vec::new();
        let mut previous_s = 0.0;
        for (line, content) in lines {
            if rows.len() == MAX_TRACE_ROWS {
                return Err(TraceError::TooManyRows { line });
            }
            let mut fields = content.split(',');
            let mut next = |column| field(line, column, fields.next());
            let t_s = next(Column::Time)?;
            let fwd_ms = next(Column::Forward)?;
            let bwd_ms = next(Column::Backward)?;
            let extra = fields.count();
            if extra > 0 {
                return Err(TraceError::ColumnCount {
                    line,
                    found: 3 + extra,
                });
            }
            check(line, Column::Time, t_s, MAX_TRACE_TIME_S)?;
            check(line, Column::Forward, fwd_ms, MAX_TRACE_DELAY_MS)?;
            check(line, Column::Backward, bwd_ms, MAX_TRACE_DELAY_MS)?;
            if !rows.is_empty() && t_s < previous_s {
                return Err(TraceError::Unsorted {
                    line,
                    t_s,
                    previous_s,
                });
            }
            previous_s = t_s;
            rows.push(TraceRow {
                at: Instant::from_secs_f64(t_s),
                fwd: Duration::from_secs_f64(fwd_ms * 1e-3),
                bwd: Duration::from_secs_f64(bwd_ms * 1e-3),
            });
        }
        if rows.is_empty() {
            return Err(TraceError::NoRows);
        }
        Ok(Trace::of(rows))
    }

    fn of(rows: Vec<TraceRow>) -> Trace {
        Trace {
            rows,
            anchor: None,
            probes: [Vec::new(), Vec::new()],
            lost: [Vec::new(), Vec::new()],
        }
    }

    /// This trace with a recorded link's probes in direction `dir`: their
    /// sequence numbers and the delays they met (a number given twice
    /// keeps its first delay). A simulator replaying it gives each of its
    /// own probes the delay of the recorded one of that number, so that
    /// its initialization pattern measures the round trips the recorded
    /// one did, and sizes its queue as that one did.
    #[must_use]
    pub fn with_probes(mut self, dir: Direction, mut probes: Vec<(u64, Duration)>) -> Self {
        // Stable: the first of a number stays first.
        probes.sort_by_key(|p| p.0);
        probes.dedup_by_key(|p| p.0);
        self.probes[dir.index()] = probes;
        self
    }

    /// What the recording says of the probe numbered `seq` in direction
    /// `dir` ([`Trace::with_probes`]).
    #[must_use]
    pub fn probe(&self, dir: Direction, seq: u64) -> RecordedProbe {
        let probes = &self.probes[dir.index()];
        match probes.binary_search_by_key(&seq, |p| p.0) {
            Ok(i) => RecordedProbe::Delayed(probes[i].1),
            Err(i) if i < probes.len() => RecordedProbe::Lost,
            Err(_) => RecordedProbe::Unrecorded,
        }
    }

    /// This trace with the spans, in direction `dir`, in which a datagram
    /// sent is lost: a recorded sample that was never released, replayed
    /// as a loss rather than as a delay.
    #[must_use]
    pub fn with_losses(mut self, dir: Direction, mut spans: Vec<(Instant, Instant)>) -> Self {
        spans.retain(|s| s.0 < s.1);
        spans.sort_by_key(|s| s.0);
        self.lost[dir.index()] = spans;
        self
    }

    /// Whether a datagram sent at `sent_at` in direction `dir` is lost
    /// ([`Trace::with_losses`]).
    #[must_use]
    pub fn lost(&self, dir: Direction, sent_at: Instant) -> bool {
        let spans = &self.lost[dir.index()];
        let after = spans.partition_point(|s| s.0 <= sent_at);
        after > 0 && sent_at < spans[after - 1].1
    }

    /// This trace, its time line tied to a link's: `at` is when the
    /// recorded link sent its first command, and a simulator replaying it
    /// shifts the trace so that its own link's first command goes out
    /// then, the handshake and initialization before it taking the first
    /// rows' delays. A recording's samples then meet the delays they met,
    /// however long the simulated set-up takes.
    #[must_use]
    pub fn with_anchor(mut self, at: Instant) -> Self {
        self.anchor = Some(at);
        self
    }

    /// When the recorded link sent its first command, if this trace is a
    /// recording's ([`Trace::with_anchor`]).
    #[must_use]
    pub fn anchor(&self) -> Option<Instant> {
        self.anchor
    }

    /// Reads and parses a trace file (at most [`MAX_TRACE_FILE_BYTES`]).
    ///
    /// # Errors
    ///
    /// [`TraceError::Io`] or [`TraceError::FileTooLarge`] if the file cannot
    /// be read, else what [`Trace::parse`] returns.
    pub fn from_path(path: impl AsRef<Path>) -> Result<Trace, TraceError> {
        let path = path.as_ref();
        let text = read_capped(path, MAX_TRACE_FILE_BYTES).map_err(|e| match e {
            ReadError::TooLarge => TraceError::FileTooLarge {
                path: path.to_path_buf(),
                max: MAX_TRACE_FILE_BYTES,
            },
            ReadError::Io(message) => TraceError::Io {
                path: path.to_path_buf(),
                message,
            },
        })?;
        Trace::parse(&text)
    }

    /// A trace from rows already in memory (e.g. generated from a model).
    ///
    /// # Errors
    ///
    /// [`TraceError::NoRows`], [`TraceError::TooManyRows`], or
    /// [`TraceError::Unsorted`] with `line` = row index + 2 (the line the row
    /// would take in a file).
    pub fn from_rows(rows: Vec<TraceRow>) -> Result<Trace, TraceError> {
        if rows.is_empty() {
            return Err(TraceError::NoRows);
        }
        if rows.len() > MAX_TRACE_ROWS {
            return Err(TraceError::TooManyRows {
                line: MAX_TRACE_ROWS + 2,
            });
        }
        if let Some(i) = rows.windows(2).position(|w| w[1].at < w[0].at) {
            return Err(TraceError::Unsorted {
                line: i + 3,
                t_s: rows[i + 1].at.as_secs_f64(),
                previous_s: rows[i].at.as_secs_f64(),
            });
        }
        Ok(Trace::of(rows))
    }

    /// The rows, in time order.
    #[must_use]
    pub fn rows(&self) -> &[TraceRow] {
        &self.rows
    }

    /// The time of the last row, from the origin: how long the trace
    /// describes (the last row's delays apply beyond it).
    #[must_use]
    pub fn duration(&self) -> Duration {
        self.rows
            .last()
            .map_or(Duration::ZERO, |r| r.at - Instant::ZERO)
    }

    /// The delay of a frame sent at `sent_at` in direction `dir`: that of the
    /// last row with `at ≤ sent_at`, or of the first row before it.
    #[must_use]
    pub fn delay(&self, dir: Direction, sent_at: Instant) -> Duration {
        let after = self.rows.partition_point(|r| r.at <= sent_at);
        let row = self.rows.get(after.saturating_sub(1)).or(self.rows.first());
        row.map_or(Duration::ZERO, |r| match dir {
            Direction::Forward => r.fwd,
            Direction::Backward => r.bwd,
        })
    }

    /// The trace as CSV text, header first, that [`Trace::parse`] reads back
    /// (times in seconds and delays in milliseconds, exact to the nanosecond).
    #[must_use]
    pub fn to_csv(&self) -> String {
        use core::fmt::Write;
        let mut out = String::with_capacity(24 * (self.rows.len() + 1));
        out.push_str(TRACE_HEADER);
        out.push('\n');
        for r in &self.rows {
            let t = r.at.as_nanos();
            let _ = writeln!(
                out,
                "{}.{:09},{},{}",
                t / 1_000_000_000,
                t % 1_000_000_000,
                Millis(r.fwd),
                Millis(r.bwd)
            );
        }
        out
    }
}

fn field(line: usize, column: Column, text: Option<&str>) -> Result<f64, TraceError> {
    let Some(text) = text else {
        let found = match column {
            Column::Time => 0,
            Column::Forward => 1,
            Column::Backward => 2,
        };
        return Err(TraceError::ColumnCount { line, found });
    };
    let text = text.trim();
    text.parse::<f64>().map_err(|_| TraceError::NotANumber {
        line,
        column,
        text: snippet(text),
    })
}

fn check(line: usize, column: Column, value: f64, max: f64) -> Result<(), TraceError> {
    if !value.is_finite() {
        Err(TraceError::NotFinite { line, column })
    } else if value < 0.0 {
        Err(TraceError::Negative {
            line,
            column,
            value,
        })
    } else if value > max {
        Err(TraceError::TooLarge {
            line,
            column,
            value,
        })
    } else {
        Ok(())
    }
}
