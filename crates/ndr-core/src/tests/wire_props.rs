//! Property tests of the frame codec: round trips, and totality of decoding
//! on arbitrary and corrupted input.

#[allow(unused_imports)]
use std::{borrow::ToOwned, boxed::Box, string::String, string::ToString, vec::Vec};
#[allow(unused_imports)]
use std::{eprintln, format, println, vec};

use crate::time::{Duration, Instant};
use crate::wire::{
    Close, Control, Echo, Frame, HEADER_LEN, Header, Hello, Kind, MAX_BUNDLE, MAX_CHANNELS,
    MAX_DATAGRAM_LEN, MAX_FRAME_LEN, Message, OlderSample, Payload, RegulationName, Role, Token,
    VERSION, WireError, encode, encoded_len, frame_len,
};
use proptest::prelude::*;

/// Finite f64s, weighted towards the awkward ones.
fn finite() -> impl Strategy<Value = f64> {
    use proptest::num::f64::{NEGATIVE, NORMAL, POSITIVE, SUBNORMAL, ZERO};
    prop_oneof![
        4 => POSITIVE | NEGATIVE | NORMAL | SUBNORMAL | ZERO,
        1 => prop::sample::select(vec![
            0.0,
            -0.0,
            f64::MAX,
            f64::MIN,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
            f64::from_bits(1),
            -f64::from_bits(1),
            f64::EPSILON,
        ]),
    ]
}

/// Any u64 except the wire's "none" sentinel, with the edges well represented.
fn not_none() -> impl Strategy<Value = u64> {
    prop_oneof![
        3 => 0..u64::MAX,
        1 => prop::sample::select(vec![0, 1, u64::MAX - 1]),
    ]
}

fn header() -> impl Strategy<Value = Header> {
    (
        any::<u64>(),
        any::<u64>(),
        prop::option::of((not_none(), any::<u64>())),
        prop::option::of(not_none()),
    )
        .prop_map(|(seq, sent_at, echo, released)| Header {
            term: 0,
            seq,
            sent_at: Instant::from_nanos(sent_at),
            echo: echo.map(|(sent_at, hold)| Echo {
                sent_at: Instant::from_nanos(sent_at),
                hold: Duration::from_nanos(hold),
            }),
            released,
        })
}

/// An owned message (Data values in a vector).
#[derive(Debug, Clone)]
enum Owned {
    Data(Vec<f64>),
    Hello(Hello),
    Control(Control),
    Close(Close),
    Token(Token),
}

impl Owned {
    fn msg(&self) -> Message<'_> {
        match self {
            Owned::Data(v) => Message::Data(v),
            Owned::Hello(h) => Message::Hello(*h),
            Owned::Control(c) => Message::Control(*c),
            Owned::Close(c) => Message::Close(*c),
            Owned::Token(t) => Message::Token(*t),
        }
    }
}

fn message() -> impl Strategy<Value = Owned> {
    prop_oneof![
        3 => prop::collection::vec(finite(), 0..=MAX_CHANNELS).prop_map(Owned::Data),
        1 => (
            (any::<bool>(), any::<u8>(), any::<u8>()),
            (1..=MAX_CHANNELS as u16, 1..=MAX_CHANNELS as u16),
            (1..=u64::MAX, any::<u64>(), any::<u64>()),
            "[ -~]{0,32}",
        )
            .prop_map(
                |((remote, mode, underflow), (command_width, state_width), (period, layout, session), name)| {
                    Owned::Hello(Hello {
                        seat: crate::wire::Seat::Control,
                        role: if remote { Role::Remote } else { Role::Base },
                        mode: mode.into(),
                        underflow: underflow.into(),
                        command_width,
                        state_width,
                        period: Duration::from_nanos(period),
                        layout,
                        session,
                        regulation: RegulationName::new(&name).expect("printable ASCII, 32 bytes at most"),
                    })
                }
            ),
        1 => (1..=u8::MAX, any::<u16>(), any::<u64>()).prop_map(|(op, ns, period)| {
            Owned::Control(Control {
                op: op.into(),
                ns,
                period: Duration::from_nanos(period),
            })
        }),
        1 => any::<u16>().prop_map(|reason| Owned::Close(Close { reason: reason.into() })),
        1 => (1..=u64::MAX).prop_map(|session| Owned::Token(Token { session })),
    ]
}

fn encoded(header: &Header, msg: &Owned) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME_LEN];
    let n = encode(header, &msg.msg(), &mut buf).expect("valid input encodes");
    buf[..n].to_vec()
}

/// Calls every accessor of a frame that passed `new_checked`.
fn touch_everything(frame: &Frame<&[u8]>) {
    let _ = (frame.kind(), frame.seq(), frame.sent_at(), frame.echo());
    let _ = (frame.released(), frame.header(), frame.as_bytes().len());
    let _ = format!("{frame:?}");
    match frame.payload() {
        Payload::Data(ch) => {
            assert!(ch.len() <= MAX_CHANNELS);
            assert!(ch.iter().all(f64::is_finite));
            let _ = (ch.get(0), ch.get(ch.len()), ch.get(usize::MAX));
            let mut dst = [0.0; MAX_CHANNELS];
            assert_eq!(ch.copy_to(&mut dst), Ok(ch.len()));
            if !ch.is_empty() {
                assert!(ch.copy_to(&mut dst[..ch.len() - 1]).is_err());
            }
        }
        Payload::Hello(h) => assert!(!h.period.is_zero()),
        Payload::Control(c) => assert_ne!(u8::from(c.op), 0),
        Payload::Close(_) => {}
        Payload::Token(t) => assert_ne!(t.session, 0),
        Payload::Applied(a) => {
            assert!(a.values.len() <= MAX_CHANNELS);
            assert!(a.values.iter().all(f64::is_finite));
        }
        Payload::Bundle(b) => {
            assert!((1..=MAX_BUNDLE).contains(&b.count()));
            assert_eq!(b.newest().len(), b.width());
            let mut above = frame.seq();
            for o in b.older() {
                assert!(o.seq < above && o.values.iter().all(f64::is_finite));
                assert_eq!(o.values.len(), b.width());
                above = o.seq;
            }
            let _ = b.session();
        }
    }
}

/// Decodes `bytes` every way there is; never panics.
fn decode_anything(bytes: &[u8]) {
    let len = frame_len(bytes);
    match Frame::new_checked(bytes) {
        Ok(frame) => {
            // A stream's framing agrees, but for a Bundle longer than any
            // frame of a stream (a datagram, never framed).
            if frame.kind() != Kind::Bundle || bytes.len() <= MAX_FRAME_LEN {
                assert_eq!(
                    len,
                    Ok(Some(bytes.len())),
                    "frame_len agrees with new_checked"
                );
            }
            touch_everything(&frame);
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn encode_then_decode_gives_the_input_back(h in header(), m in message()) {
        let bytes = encoded(&h, &m);
        prop_assert_eq!(bytes.len(), encoded_len(&m.msg()));
        prop_assert_eq!(frame_len(&bytes), Ok(Some(bytes.len())));
        prop_assert_eq!(frame_len(&bytes[..4]), Ok(Some(bytes.len())));
        let frame = Frame::new_checked(&bytes[..]).expect("encoded frame decodes");
        prop_assert_eq!(frame.kind(), m.msg().kind());
        prop_assert_eq!(frame.header(), h);
        match (frame.payload(), &m) {
            (Payload::Data(ch), Owned::Data(v)) => {
                prop_assert_eq!(ch.len(), v.len());
                // Bit-exact: -0.0 and subnormals survive.
                let got: Vec<u64> = ch.iter().map(f64::to_bits).collect();
                let want: Vec<u64> = v.iter().map(|x| x.to_bits()).collect();
                prop_assert_eq!(got, want);
                let mut dst = vec![0.0; v.len()];
                prop_assert_eq!(ch.copy_to(&mut dst), Ok(v.len()));
                prop_assert!(dst.iter().zip(v).all(|(a, b)| a.to_bits() == b.to_bits()));
            }
            (Payload::Hello(got), Owned::Hello(want)) => prop_assert_eq!(got, *want),
            (Payload::Control(got), Owned::Control(want)) => prop_assert_eq!(got, *want),
            (Payload::Close(got), Owned::Close(want)) => prop_assert_eq!(got, *want),
            (Payload::Token(got), Owned::Token(want)) => prop_assert_eq!(got, *want),
            (p, m) => prop_assert!(false, "decoded {:?} from {:?}", p, m),
        }
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..3000)) {
        decode_anything(&bytes);
    }

    #[test]
    fn arbitrary_bytes_with_a_plausible_prefix_never_panic(
        len in 0u32..2200,
        kind in 0u8..6,
        rest in prop::collection::vec(any::<u8>(), 0..2200),
    ) {
        // Random bytes rarely pass the length and version checks; this gets deeper.
        let mut bytes = len.to_le_bytes().to_vec();
        bytes.extend_from_slice(&[VERSION, kind, 0, 0]);
        bytes.extend_from_slice(&rest);
        bytes.truncate(usize::try_from(len).unwrap().max(8));
        decode_anything(&bytes);
    }

    #[test]
    fn mutated_frames_never_panic(
        h in header(),
        m in message(),
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        cut in any::<prop::sample::Index>(),
        truncate in any::<bool>(),
    ) {
        let mut bytes = encoded(&h, &m);
        for (at, value) in flips {
            let i = at.index(bytes.len());
            bytes[i] = value;
        }
        if truncate {
            bytes.truncate(cut.index(bytes.len() + 1));
        }
        decode_anything(&bytes);
    }

    #[test]
    fn truncated_frames_are_truncated(h in header(), m in message(), cut in any::<prop::sample::Index>()) {
        let bytes = encoded(&h, &m);
        let n = cut.index(bytes.len());
        let needed = if n < 4 { 4 } else { bytes.len() };
        prop_assert_eq!(
            Frame::new_checked(&bytes[..n]).map(|f| f.kind()),
            Err(WireError::Truncated { needed, got: n })
        );
    }

    #[test]
    fn frame_len_never_panics_and_bounds(prefix in prop::collection::vec(any::<u8>(), 0..8)) {
        match frame_len(&prefix) {
            Ok(None) => prop_assert!(prefix.len() < 4),
            Ok(Some(n)) => prop_assert!((HEADER_LEN..=MAX_FRAME_LEN).contains(&n)),
            Err(e) => prop_assert!(matches!(e, WireError::LengthOutOfRange(_))),
        }
    }

    #[test]
    fn encode_is_total(
        h in header(),
        values in prop::collection::vec(any::<f64>(), 0..300),
        buf_len in 0usize..2200,
        period in any::<u64>(),
        op in any::<u8>(),
        sentinel_echo in any::<bool>(),
    ) {
        let mut h = h;
        if sentinel_echo {
            h.echo = Some(Echo { sent_at: Instant::from_nanos(u64::MAX), hold: Duration::ZERO });
        }
        let hello = Hello {
            seat: crate::wire::Seat::Control,
            role: Role::Base, mode: 0.into(), underflow: 0.into(), command_width: 1, state_width: 1,
            period: Duration::from_nanos(period), layout: 0, session: 0,
            regulation: RegulationName::lossy("adaptive"),
        };
        let control = Control { op: op.into(), ns: 1, period: Duration::from_nanos(period) };
        let mut buf = vec![0u8; buf_len];
        for msg in [Message::Data(&values), Message::Hello(hello), Message::Control(control)] {
            if let Ok(n) = encode(&h, &msg, &mut buf) {
                // Whatever encode accepts, new_checked accepts.
                prop_assert_eq!(n, encoded_len(&msg));
                let frame = Frame::new_checked(&buf[..n]);
                prop_assert!(frame.is_ok(), "{:?}", frame);
            }
        }
    }
}

/// A bundle to encode: its session, width, and per sample (newest first)
/// the gap to the sample ahead of it, a stamp, what it answers, values.
type BundleCase = (u64, Vec<(u64, u64, Option<u64>, Vec<f64>)>);

fn bundle_case() -> impl Strategy<Value = BundleCase> {
    (any::<u64>(), 0usize..=40, 1usize..=MAX_BUNDLE).prop_flat_map(|(session, width, count)| {
        let sample = (
            1u64..1000,
            any::<u64>(),
            prop::option::of(not_none()),
            prop::collection::vec(finite(), width),
        );
        (Just(session), prop::collection::vec(sample, count))
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1000))]

    #[test]
    fn a_bundle_decodes_to_its_samples_and_survives_mutation(
        h in header(),
        (session, samples) in bundle_case(),
        (repeat, missed) in (any::<u8>(), any::<u32>()),
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
    ) {
        let mut h = h;
        h.seq = h.seq.max(1 << 20);
        let mut seq = h.seq;
        let older: Vec<OlderSample<'_>> = samples[1..]
            .iter()
            .map(|(gap, sent_at, released, values)| {
                seq -= gap;
                OlderSample { seq, sent_at: Instant::from_nanos(*sent_at), released: *released, values }
            })
            .collect();
        let msg = Message::Bundle { session, repeat, missed, newest: &samples[0].3, older: &older };
        let mut buf = vec![0u8; MAX_DATAGRAM_LEN];
        let n = encode(&h, &msg, &mut buf).expect("a valid bundle encodes");
        prop_assert_eq!(n, encoded_len(&msg));
        let frame = Frame::new_checked(&buf[..n]).expect("it decodes");
        prop_assert_eq!(frame.header(), h);
        let Payload::Bundle(b) = frame.payload() else {
            return Err(TestCaseError::fail("not a bundle"));
        };
        prop_assert_eq!((b.session(), b.count()), (session, samples.len()));
        prop_assert_eq!((b.repeat(), b.missed()), (repeat, missed));
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        prop_assert_eq!(bits(&b.newest().iter().collect::<Vec<_>>()), bits(&samples[0].3));
        for (got, want) in b.older().zip(&older) {
            prop_assert_eq!((got.seq, got.sent_at, got.released), (want.seq, want.sent_at, want.released));
            prop_assert_eq!(bits(&got.values.iter().collect::<Vec<_>>()), bits(want.values));
        }
        touch_everything(&frame);
        let mut bytes = buf[..n].to_vec();
        for (at, value) in flips {
            let i = at.index(bytes.len());
            bytes[i] = value;
        }
        decode_anything(&bytes);
    }
}
