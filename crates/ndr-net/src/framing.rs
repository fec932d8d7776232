//! Splitting a byte stream into frames.
//!
//! TCP delivers bytes, not frames: a read may hold half a frame or several.
//! The [`Deframer`] accumulates bytes in a fixed buffer and hands out whole
//! frames, checking each frame's length prefix as soon as its four bytes are
//! in. A link knows the largest frame its peer may send (its channels are
//! bounded), so its deframer holds a few of those rather than one of
//! [`MAX_FRAME_LEN`] bytes: 2 KiB less per link end, a thousand links at a
//! time.

use core::fmt;

use ndr_core::wire::{self, Control, Frame, HEADER_LEN, Hello, MAX_FRAME_LEN, WireError};

/// Frames of the largest size a [`Deframer`] holds at once (what one read
/// can take when frames wait in the socket).
pub(crate) const READ_FRAMES: usize = 4;

/// The smallest limit a [`Deframer`] takes: the largest frame whose size
/// does not follow the link's channels (a Hello naming its regulation at
/// length, or a Control; a Close is shorter).
pub(crate) const MIN_MAX_FRAME: usize = HEADER_LEN
    + if Hello::MAX_LEN > Control::LEN {
        Hello::MAX_LEN
    } else {
        Control::LEN
    };

/// A stream that cannot be deframed; the connection must be closed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum FramingError {
    /// The bytes are not a valid frame.
    Wire(WireError),
    /// A valid length, but longer than this deframer's limit: the peer sends
    /// more channels than the link carries.
    TooLong {
        /// The frame's length.
        len: usize,
        /// The limit.
        max: usize,
    },
}

impl fmt::Display for FramingError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FramingError::Wire(e) => write!(f, "bad frame from peer, closing the connection: {e}"),
            FramingError::TooLong { len, max } => write!(
                f,
                "a {len}-byte frame from peer, longer than this link's largest ({max} bytes): \
                 it sends more channels than agreed; closing the connection"
            ),
        }
    }
}

impl std::error::Error for FramingError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            FramingError::Wire(e) => Some(e),
            FramingError::TooLong { .. } => None,
        }
    }
}

impl From<WireError> for FramingError {
    fn from(e: WireError) -> Self {
        FramingError::Wire(e)
    }
}

/// Reassembles frames from stream reads, with memory bounded by one frame.
///
/// ```no_run
/// # fn read(_: &mut [u8]) -> usize { 0 }
/// use ndr_net::Deframer;
///
/// let mut deframer = Deframer::new();
/// loop {
///     let n = read(deframer.spare());
///     deframer.filled(n);
///     while let Some(frame) = deframer.next_frame()? {
///         // handle `frame` (a checked `ndr_core::wire::Frame`)
///         # let _ = frame;
///     }
/// }
/// # Ok::<(), ndr_net::FramingError>(())
/// ```
#[derive(Clone)]
pub struct Deframer {
    buf: Box<[u8]>,
    /// The longest frame accepted.
    max: usize,
    /// Start of the unconsumed bytes.
    start: usize,
    /// End of the bytes read so far.
    end: usize,
    frames: u64,
}

impl fmt::Debug for Deframer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Deframer")
            .field("buffered", &self.buffered())
            .field("frames", &self.frames)
            .finish()
    }
}

impl Default for Deframer {
    fn default() -> Self {
        Self::new()
    }
}

impl Deframer {
    /// An empty deframer for frames of any valid length (up to
    /// [`MAX_FRAME_LEN`]).
    #[must_use]
    pub fn new() -> Self {
        Self::with_max_frame(MAX_FRAME_LEN)
    }

    /// An empty deframer for frames of at most `max_frame` bytes (clamped
    /// from the largest frame of fixed size, a Hello or a Control, to
    /// [`MAX_FRAME_LEN`]), holding four of them (at most `MAX_FRAME_LEN`
    /// bytes); a longer frame is [`FramingError::TooLong`].
    #[must_use]
    pub fn with_max_frame(max_frame: usize) -> Self {
        let max = max_frame.clamp(MIN_MAX_FRAME, MAX_FRAME_LEN);
        let room = max.saturating_mul(READ_FRAMES).min(MAX_FRAME_LEN).max(max);
        Deframer {
            buf: vec![0; room].into_boxed_slice(),
            max,
            start: 0,
            end: 0,
            frames: 0,
        }
    }

    /// The longest frame accepted.
    #[must_use]
    pub fn max_frame(&self) -> usize {
        self.max
    }

    /// Room to read into; call [`filled`](Self::filled) with the count read.
    /// Never empty while a frame is incomplete.
    pub fn spare(&mut self) -> &mut [u8] {
        if self.start > 0 {
            // Move the partial frame (under one frame long) to the front so
            // that reads are never starved of room.
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        &mut self.buf[self.end..]
    }

    /// Records that `n` bytes were written at the start of [`spare`](Self::spare);
    /// `n` larger than the spare room is clamped.
    pub fn filled(&mut self, n: usize) {
        self.end = (self.end + n).min(self.buf.len());
    }

    /// Copies `bytes` in as far as they fit; returns how many were taken
    /// (drain frames with [`next_frame`](Self::next_frame), then offer the rest).
    pub fn extend(&mut self, bytes: &[u8]) -> usize {
        let spare = self.spare();
        let n = bytes.len().min(spare.len());
        spare[..n].copy_from_slice(&bytes[..n]);
        self.filled(n);
        n
    }

    /// The next complete frame, `Ok(None)` if more bytes are needed.
    ///
    /// An error means the stream is corrupt (bad length prefix or an invalid
    /// frame); nothing more can be trusted from it.
    pub fn next_frame(&mut self) -> Result<Option<Frame<&[u8]>>, FramingError> {
        let pending = &self.buf[self.start..self.end];
        let Some(len) = wire::frame_len(pending)? else {
            self.compact_if_empty();
            return Ok(None);
        };
        if len > self.max {
            return Err(FramingError::TooLong { len, max: self.max });
        }
        if pending.len() < len {
            return Ok(None);
        }
        let at = self.start;
        self.start += len;
        self.frames += 1;
        Ok(Some(Frame::new_checked(&self.buf[at..at + len])?))
    }

    fn compact_if_empty(&mut self) {
        if self.start == self.end {
            self.start = 0;
            self.end = 0;
        }
    }

    /// Bytes received but not yet handed out as frames.
    #[must_use]
    pub fn buffered(&self) -> usize {
        self.end - self.start
    }

    /// Frames handed out so far.
    #[must_use]
    pub fn frames(&self) -> u64 {
        self.frames
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndr_core::time::Instant;
    use ndr_core::wire::{Header, Message, Payload};

    fn data_frame(seq: u64, values: &[f64]) -> Vec<u8> {
        let header = Header {
            term: 0,
            seq,
            sent_at: Instant::from_millis(seq),
            echo: None,
            released: None,
        };
        let mut buf = vec![0; MAX_FRAME_LEN];
        let n = wire::encode(&header, &Message::Data(values), &mut buf).unwrap();
        buf.truncate(n);
        buf
    }

    fn first_channel(frame: &Frame<&[u8]>) -> f64 {
        match frame.payload() {
            Payload::Data(ch) => ch.get(0).unwrap(),
            other => panic!("expected data, got {other:?}"),
        }
    }

    #[test]
    fn reassembles_frames_split_and_merged_across_reads() {
        let mut stream = Vec::new();
        for seq in 0..50u64 {
            stream.extend(data_frame(seq, &vec![seq as f64; (seq % 9) as usize + 1]));
        }
        // Feed in awkward chunk sizes: 1, 2, 3, ... bytes.
        let mut d = Deframer::new();
        let (mut at, mut chunk, mut seen) = (0, 1, Vec::new());
        while at < stream.len() {
            let n = chunk.min(stream.len() - at);
            assert_eq!(d.extend(&stream[at..at + n]), n);
            at += n;
            chunk = chunk % 97 + 1;
            while let Some(f) = d.next_frame().unwrap() {
                assert_eq!(first_channel(&f), f.seq() as f64);
                seen.push(f.seq());
            }
        }
        assert_eq!(seen, (0..50).collect::<Vec<_>>());
        assert_eq!(d.buffered(), 0);
        assert_eq!(d.frames(), 50);
    }

    #[test]
    fn a_full_size_frame_fits_after_a_partial_one() {
        let big = data_frame(1, &vec![1.0; wire::MAX_CHANNELS]);
        assert_eq!(big.len(), HEADER_LEN + 8 * wire::MAX_CHANNELS);
        let small = data_frame(0, &[0.0]);
        let mut d = Deframer::new();
        d.extend(&small);
        d.extend(&big[..100]);
        assert_eq!(d.next_frame().unwrap().unwrap().seq(), 0);
        assert!(d.next_frame().unwrap().is_none());
        let mut at = 100;
        while at < big.len() {
            at += d.extend(&big[at..]);
        }
        assert_eq!(d.next_frame().unwrap().unwrap().seq(), 1);
    }

    #[test]
    fn an_absurd_length_is_refused_before_buffering() {
        let mut d = Deframer::new();
        d.extend(&u32::MAX.to_le_bytes());
        assert!(matches!(d.next_frame(), Err(FramingError::Wire(_))));
        let mut d = Deframer::new();
        d.extend(&[1, 0, 0, 0]);
        assert!(d.next_frame().is_err());
    }

    #[test]
    fn a_deframer_for_nine_channels_is_small_and_refuses_a_longer_frame() {
        let sample = |seq: u64| [seq as f64, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];
        let nine = data_frame(0, &sample(0)).len();
        assert!(nine > MIN_MAX_FRAME);
        let mut d = Deframer::with_max_frame(nine);
        assert_eq!(d.max_frame(), nine);
        assert_eq!(d.spare().len(), nine * READ_FRAMES);
        // Frames of the limit, split and merged across reads, still pass.
        let mut stream = Vec::new();
        for seq in 0..20u64 {
            stream.extend(data_frame(seq, &sample(seq)));
        }
        let (mut at, mut seen) = (0, 0u64);
        while at < stream.len() {
            let n = 7.min(stream.len() - at);
            at += d.extend(&stream[at..at + n]);
            while let Some(f) = d.next_frame().unwrap() {
                assert_eq!(f.seq(), seen);
                seen += 1;
            }
        }
        assert_eq!(seen, 20);
        d.extend(&data_frame(20, &[1.0; 10])[..8]);
        let err = d.next_frame().unwrap_err();
        assert_eq!(
            err,
            FramingError::TooLong {
                len: nine + 8,
                max: nine
            }
        );
        assert!(err.to_string().contains("more channels"), "{err}");
        // Below the largest fixed-size frame (a Hello), the limit is raised
        // to it: a link of one value each way still reads its peer's Hello.
        assert_eq!(Deframer::with_max_frame(0).max_frame(), MIN_MAX_FRAME);
        assert_eq!(MIN_MAX_FRAME, HEADER_LEN + Hello::MAX_LEN);
    }

    #[test]
    fn garbage_with_a_plausible_length_is_refused() {
        let mut frame = data_frame(3, &[1.0, 2.0]);
        frame[4] = 99; // version
        let mut d = Deframer::new();
        d.extend(&frame);
        let err = d.next_frame().unwrap_err();
        assert!(err.to_string().contains("version"), "{err}");
    }
}
