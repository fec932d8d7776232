//! Splitting a byte stream into frames.
//!
//! TCP delivers bytes, not frames: a read may hold half a frame or several.
//! The [`Deframer`] accumulates bytes in a fixed buffer of
//! [`MAX_FRAME_LEN`] bytes and hands out whole frames, checking each frame's
//! length prefix as soon as its four bytes are in.

use core::fmt;

use ndr_core::wire::{self, Frame, MAX_FRAME_LEN, WireError};

/// A stream that cannot be deframed; the connection must be closed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FramingError {
    /// The bytes are not a valid frame.
    Wire(WireError),
}

impl fmt::Display for FramingError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FramingError::Wire(e) => write!(f, "bad frame from peer, closing the connection: {e}"),
        }
    }
}

impl std::error::Error for FramingError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            FramingError::Wire(e) => Some(e),
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
    buf: Box<[u8; MAX_FRAME_LEN]>,
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
    /// An empty deframer.
    #[must_use]
    pub fn new() -> Self {
        Deframer {
            buf: Box::new([0; MAX_FRAME_LEN]),
            start: 0,
            end: 0,
            frames: 0,
        }
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
        assert_eq!(big.len(), MAX_FRAME_LEN);
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
    fn garbage_with_a_plausible_length_is_refused() {
        let mut frame = data_frame(3, &[1.0, 2.0]);
        frame[4] = 99; // version
        let mut d = Deframer::new();
        d.extend(&frame);
        let err = d.next_frame().unwrap_err();
        assert!(err.to_string().contains("version"), "{err}");
    }
}
