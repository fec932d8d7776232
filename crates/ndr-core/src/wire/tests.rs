use std::format;
use std::string::ToString;
use std::vec::Vec;

use super::*;

fn header() -> Header {
    Header {
        term: 0x1234,
        seq: 9,
        sent_at: Instant::from_millis(3),
        echo: Some(Echo {
            sent_at: Instant::from_millis(2),
            hold: Duration::from_micros(40),
        }),
        released: Some(8),
    }
}

fn hello() -> Hello {
    Hello {
        seat: Seat::WaitForControl,
        role: Role::Remote,
        mode: ModeCode::PaperStatic,
        underflow: UnderflowCode::DropLate,
        command_width: 2,
        state_width: 5,
        period: Duration::from_millis(200),
        layout: 0x0123_4567_89ab_cdef,
        session: 42,
        regulation: RegulationName::NONE,
    }
}

fn control() -> Control {
    Control {
        op: ControlOp::PauseRequest,
        ns: 0,
        period: Duration::ZERO,
    }
}

/// Encodes a valid frame into a vector.
fn frame_bytes(msg: &Message<'_>) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME_LEN];
    let n = encode(&header(), msg, &mut buf).unwrap();
    buf[..n].to_vec()
}

fn data(values: &[f64]) -> Vec<u8> {
    frame_bytes(&Message::Data(values))
}

fn decode(bytes: &[u8]) -> Result<Kind, WireError> {
    Frame::new_checked(bytes).map(|f| f.kind())
}

fn with(mut bytes: Vec<u8>, at: usize, value: u8) -> Vec<u8> {
    bytes[at] = value;
    bytes
}

#[test]
fn round_trip_every_kind() {
    let values = [1.0, -0.0, f64::MIN_POSITIVE / 4.0, f64::MAX];
    let close = Close {
        reason: CloseReason::Timeout,
    };
    for msg in [
        Message::Data(&values),
        Message::Data(&[]),
        Message::Hello(hello()),
        Message::Control(control()),
        Message::Close(close),
    ] {
        let bytes = frame_bytes(&msg);
        assert_eq!(bytes.len(), encoded_len(&msg));
        let frame = Frame::new_checked(&bytes[..]).unwrap();
        assert_eq!(frame.kind(), msg.kind());
        assert_eq!(frame.payload().kind(), msg.kind());
        assert_eq!(frame.header(), header());
        match (frame.payload(), msg) {
            (Payload::Data(ch), Message::Data(v)) => {
                let got: Vec<u64> = ch.iter().map(f64::to_bits).collect();
                let want: Vec<u64> = v.iter().map(|x| x.to_bits()).collect();
                assert_eq!(got, want);
            }
            (Payload::Hello(h), Message::Hello(m)) => assert_eq!(h, m),
            (Payload::Control(c), Message::Control(m)) => assert_eq!(c, m),
            (Payload::Close(c), Message::Close(m)) => assert_eq!(c, m),
            (p, m) => panic!("{p:?} vs {m:?}"),
        }
        assert_eq!(frame.as_bytes(), &bytes[..]);
        assert_eq!(frame.into_inner(), &bytes[..]);
    }
}

#[test]
fn none_fields_use_the_sentinel() {
    let h = Header {
        term: 0,
        seq: 0,
        sent_at: Instant::ZERO,
        echo: None,
        released: None,
    };
    let mut buf = [0u8; MAX_FRAME_LEN];
    let n = encode(&h, &Message::Data(&[]), &mut buf).unwrap();
    assert_eq!(&buf[24..32], &[0xff; 8]);
    assert_eq!(&buf[32..40], &[0; 8]);
    assert_eq!(&buf[40..48], &[0xff; 8]);
    let frame = Frame::new_checked(&buf[..n]).unwrap();
    assert_eq!(frame.echo(), None);
    assert_eq!(frame.released(), None);
    assert_eq!(frame.header(), h);
}

#[test]
fn frame_len_reads_and_bounds_the_prefix() {
    assert_eq!(frame_len(&[]), Ok(None));
    assert_eq!(frame_len(&[48, 0, 0]), Ok(None));
    assert_eq!(frame_len(&[48, 0, 0, 0]), Ok(Some(48)));
    assert_eq!(frame_len(&[0x48, 0x08, 0, 0, 9]), Ok(Some(MAX_FRAME_LEN)));
    assert_eq!(
        frame_len(&[47, 0, 0, 0]),
        Err(WireError::LengthOutOfRange(47))
    );
    assert_eq!(
        frame_len(&[0x49, 0x08, 0, 0]),
        Err(WireError::LengthOutOfRange(2121))
    );
    assert_eq!(
        frame_len(&[0xff; 4]),
        Err(WireError::LengthOutOfRange(u32::MAX))
    );
}

#[test]
fn error_truncated() {
    assert_eq!(decode(&[]), Err(WireError::Truncated { needed: 4, got: 0 }));
    assert_eq!(
        decode(&[72, 0]),
        Err(WireError::Truncated { needed: 4, got: 2 })
    );
    let bytes = data(&[1.0, 2.0, 3.0]);
    for cut in 4..bytes.len() {
        assert_eq!(
            decode(&bytes[..cut]),
            Err(WireError::Truncated {
                needed: 72,
                got: cut
            })
        );
    }
}

#[test]
fn error_length_out_of_range() {
    let bytes = with(data(&[]), 0, 40);
    assert_eq!(decode(&bytes), Err(WireError::LengthOutOfRange(40)));
}

#[test]
fn error_length_mismatch() {
    let mut bytes = data(&[1.0]);
    bytes.extend_from_slice(&data(&[2.0]));
    assert_eq!(
        decode(&bytes),
        Err(WireError::LengthMismatch {
            field: 56,
            actual: 112
        })
    );
}

#[test]
fn error_unsupported_version() {
    let bytes = with(frame_bytes(&Message::Hello(hello())), 4, 1);
    let err = decode(&bytes).unwrap_err();
    assert_eq!(err, WireError::UnsupportedVersion(1));
    assert_eq!(err.close_reason(), CloseReason::VersionMismatch);
    assert_eq!(
        err.to_string(),
        "peer speaks ndr wire version 1, this build speaks 5; upgrade the older side \
         (version 5 came with the regulation's name in the Hello, version 4 with observers \
         and control terms)"
    );
}

#[test]
fn error_width_out_of_range_names_the_direction() {
    let good = frame_bytes(&Message::Hello(hello()));
    for (offset, width, which) in [(52, 0u16, "command"), (54, 257, "state")] {
        let mut bytes = good.clone();
        bytes[offset..offset + 2].copy_from_slice(&width.to_le_bytes());
        let err = decode(&bytes).unwrap_err();
        assert_eq!(err, WireError::WidthOutOfRange { width, offset });
        assert!(err.to_string().contains(which), "{err}");
    }
    let mut wide = hello();
    wide.command_width = 300;
    let mut buf = [0u8; MAX_FRAME_LEN];
    assert_eq!(
        encode(&header(), &Message::Hello(wide), &mut buf),
        Err(WireError::WidthOutOfRange {
            width: 300,
            offset: 52
        })
    );
}

#[test]
fn error_unknown_kind() {
    for kind in [0, 8, 255] {
        let bytes = with(data(&[]), 5, kind);
        assert_eq!(decode(&bytes), Err(WireError::UnknownKind(kind)));
    }
    assert_eq!(Kind::try_from(9), Err(WireError::UnknownKind(9)));
    for kind in [
        Kind::Data,
        Kind::Hello,
        Kind::Control,
        Kind::Close,
        Kind::Bundle,
        Kind::Token,
        Kind::Applied,
    ] {
        assert_eq!(Kind::try_from(u8::from(kind)), Ok(kind));
    }
}

#[test]
fn applied_round_trips_and_is_checked() {
    let msg = Message::Applied {
        seq: 7,
        sent_at: Instant::from_millis(5),
        applied_at: Instant::from_millis(9),
        values: &[1.0, -2.5],
    };
    let bytes = frame_bytes(&msg);
    assert_eq!(bytes.len(), HEADER_LEN + 24 + 16);
    let frame = Frame::new_checked(&bytes[..]).unwrap();
    let Payload::Applied(a) = frame.payload() else {
        panic!("an Applied frame");
    };
    assert_eq!(
        (a.seq, a.sent_at, a.applied_at),
        (7, Instant::from_millis(5), Instant::from_millis(9))
    );
    assert!(a.values.iter().eq([1.0, -2.5]));
    // Too short for its fixed fields, a value cut in half, a NaN.
    let mut short = bytes[..HEADER_LEN + 20].to_vec();
    short[0] = (HEADER_LEN + 20) as u8;
    assert_eq!(
        decode(&short),
        Err(WireError::BadPayloadLength {
            kind: Kind::Applied,
            len: 20
        })
    );
    let mut cut = bytes[..bytes.len() - 4].to_vec();
    cut[0] = cut.len() as u8;
    assert_eq!(
        decode(&cut),
        Err(WireError::BadPayloadLength {
            kind: Kind::Applied,
            len: 36
        })
    );
    let mut nan = bytes.clone();
    nan[HEADER_LEN + 32..].copy_from_slice(&f64::NAN.to_le_bytes());
    assert_eq!(decode(&nan), Err(WireError::NonFinite { index: 1 }));
    let mut buf = [0u8; MAX_FRAME_LEN];
    let applied = |values| Message::Applied {
        seq: 7,
        sent_at: Instant::from_millis(5),
        applied_at: Instant::from_millis(9),
        values,
    };
    let bad = applied(&[f64::INFINITY]);
    assert_eq!(
        encode(&header(), &bad, &mut buf),
        Err(WireError::NonFinite { index: 0 })
    );
    // The largest Applied frame is the largest frame.
    let wide = [0.0; MAX_CHANNELS];
    let n = encode(&header(), &applied(&wide), &mut buf).unwrap();
    assert_eq!(n, MAX_FRAME_LEN);
}

#[test]
fn term_is_any_value_at_offset_6() {
    let bytes = with(data(&[]), 7, 0x80);
    let frame = Frame::new_checked(&bytes[..]).unwrap();
    assert_eq!(frame.term(), 0x8034);
    assert_eq!(frame.header().term, 0x8034);
}

#[test]
fn error_bad_seat() {
    let bytes = frame_bytes(&Message::Hello(hello()));
    for (code, seat) in [
        (0, Seat::Control),
        (1, Seat::Observe),
        (2, Seat::WaitForControl),
    ] {
        let Payload::Hello(h) = Frame::new_checked(with(bytes.clone(), 51, code))
            .unwrap()
            .payload()
        else {
            panic!("a Hello");
        };
        assert_eq!(h.seat, seat);
    }
    assert_eq!(decode(&with(bytes, 51, 3)), Err(WireError::BadSeat(3)));
}

#[test]
fn error_hold_without_echo() {
    let mut bytes = data(&[]);
    bytes[24..32].copy_from_slice(&[0xff; 8]);
    assert_eq!(decode(&bytes), Err(WireError::HoldWithoutEcho));
    // With a zero hold, a NONE echo is fine.
    bytes[32..40].copy_from_slice(&[0; 8]);
    assert_eq!(decode(&bytes), Ok(Kind::Data));
}

#[test]
fn error_bad_payload_length() {
    // Data: not a whole number of f64.
    let mut bytes = data(&[1.0]);
    bytes.truncate(53);
    bytes[0] = 53;
    assert_eq!(
        decode(&bytes),
        Err(WireError::BadPayloadLength {
            kind: Kind::Data,
            len: 5
        })
    );
    // Fixed-size kinds: one byte short and one byte long (a Hello's size
    // is checked in `a_hello_s_regulation_name_is_printable_ascii_and_bounded`).
    for msg in [
        Message::Control(control()),
        Message::Close(Close {
            reason: CloseReason::Normal,
        }),
    ] {
        let good = frame_bytes(&msg);
        let payload = good.len() - HEADER_LEN;
        let mut short = good.clone();
        short.pop();
        short[0] -= 1;
        let mut long = good.clone();
        long.push(0);
        long[0] += 1;
        for (bytes, len) in [(short, payload - 1), (long, payload + 1)] {
            assert_eq!(
                decode(&bytes),
                Err(WireError::BadPayloadLength {
                    kind: msg.kind(),
                    len
                })
            );
        }
    }
}

#[test]
fn error_too_many_channels() {
    let values = [0.0; MAX_CHANNELS + 1];
    let mut buf = [0u8; 2 * MAX_FRAME_LEN];
    assert_eq!(
        encode(&header(), &Message::Data(&values), &mut buf),
        Err(WireError::TooManyChannels(MAX_CHANNELS + 1))
    );
    assert_eq!(
        encode(&header(), &Message::Data(&values[..MAX_CHANNELS]), &mut buf),
        Ok(HEADER_LEN + 8 * MAX_CHANNELS)
    );
    // A payload view that is too long (never reachable through a frame).
    assert_eq!(
        Channels::check(&[0; 8 * (MAX_CHANNELS + 1)]),
        Err(WireError::TooManyChannels(MAX_CHANNELS + 1))
    );
}

#[test]
fn error_non_finite_on_decode_and_encode() {
    let bad = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, -f64::NAN];
    let mut buf = [0u8; MAX_FRAME_LEN];
    for v in bad {
        assert_eq!(
            encode(&header(), &Message::Data(&[0.0, 1.0, v]), &mut buf),
            Err(WireError::NonFinite { index: 2 })
        );
        let mut bytes = data(&[0.0, 1.0, 2.0]);
        bytes[56..64].copy_from_slice(&v.to_le_bytes());
        assert_eq!(decode(&bytes), Err(WireError::NonFinite { index: 1 }));
    }
    // A signalling NaN and a NaN with payload bits are caught too.
    let mut bytes = data(&[0.0]);
    bytes[48..56].copy_from_slice(&0x7ff0_0000_0000_0001u64.to_le_bytes());
    assert_eq!(decode(&bytes), Err(WireError::NonFinite { index: 0 }));
    bytes[48..56].copy_from_slice(&0xfff8_dead_beef_0000u64.to_le_bytes());
    assert_eq!(decode(&bytes), Err(WireError::NonFinite { index: 0 }));
    // The largest finite values pass.
    assert_eq!(decode(&data(&[f64::MAX, f64::MIN])), Ok(Kind::Data));
}

#[test]
fn error_bad_role() {
    let bytes = with(frame_bytes(&Message::Hello(hello())), 48, 7);
    assert_eq!(decode(&bytes), Err(WireError::BadRole(7)));
    assert_eq!(Role::try_from(2), Err(WireError::BadRole(2)));
    assert_eq!(Role::try_from(0), Ok(Role::Base));
    assert_eq!(u8::from(Role::Remote), 1);
    assert_eq!(Role::Base.peer(), Role::Remote);
}

#[test]
fn error_zero_period() {
    let mut bytes = frame_bytes(&Message::Hello(hello()));
    bytes[56..64].copy_from_slice(&[0; 8]);
    assert_eq!(decode(&bytes), Err(WireError::ZeroPeriod));
    let mut h = hello();
    h.period = Duration::ZERO;
    let mut buf = [0u8; MAX_FRAME_LEN];
    assert_eq!(
        encode(&header(), &Message::Hello(h), &mut buf),
        Err(WireError::ZeroPeriod)
    );
}

#[test]
fn error_zero_control_op() {
    let bytes = with(frame_bytes(&Message::Control(control())), 48, 0);
    assert_eq!(decode(&bytes), Err(WireError::ZeroControlOp));
    let mut buf = [0u8; MAX_FRAME_LEN];
    let c = Control {
        op: ControlOp::Unknown(0),
        ..control()
    };
    assert_eq!(
        encode(&header(), &Message::Control(c), &mut buf),
        Err(WireError::ZeroControlOp)
    );
    // Unknown non-zero ops are the endpoint's business.
    let bytes = with(frame_bytes(&Message::Control(control())), 48, 200);
    assert_eq!(decode(&bytes), Ok(Kind::Control));
    let frame = Frame::new_checked(&bytes[..]).unwrap();
    let Payload::Control(c) = frame.payload() else {
        panic!("a Control frame: {frame:?}")
    };
    assert_eq!(c.op, ControlOp::Unknown(200));
}

#[test]
fn error_zero_token() {
    let token = Message::Token(Token { session: 0x0102 });
    let bytes = frame_bytes(&token);
    assert_eq!(bytes.len(), HEADER_LEN + Token::LEN);
    assert_eq!(decode(&bytes), Ok(Kind::Token));
    let mut zero = bytes.clone();
    zero[48..56].copy_from_slice(&[0; 8]);
    assert_eq!(decode(&zero), Err(WireError::ZeroToken));
    let mut buf = [0u8; MAX_FRAME_LEN];
    assert_eq!(
        encode(&header(), &Message::Token(Token { session: 0 }), &mut buf),
        Err(WireError::ZeroToken)
    );
    let mut short = bytes;
    short.truncate(HEADER_LEN + 4);
    short[0..4].copy_from_slice(&(HEADER_LEN as u32 + 4).to_le_bytes());
    assert_eq!(
        decode(&short),
        Err(WireError::BadPayloadLength {
            kind: Kind::Token,
            len: 4
        })
    );
}

#[test]
fn error_reserved_not_zero_at_every_reserved_byte() {
    let cases = [
        (
            frame_bytes(&Message::Control(control())),
            &[49, 52, 53, 54, 55][..],
        ),
        (
            frame_bytes(&Message::Close(Close {
                reason: CloseReason::VersionMismatch,
            })),
            &[50, 51, 52, 53, 54, 55][..],
        ),
    ];
    for (good, offsets) in cases {
        assert!(decode(&good).is_ok());
        for &offset in offsets {
            let bytes = with(good.clone(), offset, 1);
            assert_eq!(decode(&bytes), Err(WireError::ReservedNotZero { offset }));
        }
    }
}

#[test]
fn error_sentinel_value_on_encode() {
    let mut buf = [0u8; MAX_FRAME_LEN];
    let mut h = header();
    h.echo = Some(Echo {
        sent_at: Instant::from_nanos(u64::MAX),
        hold: Duration::ZERO,
    });
    assert_eq!(
        encode(&h, &Message::Data(&[]), &mut buf),
        Err(WireError::SentinelValue { offset: 24 })
    );
    let mut h = header();
    h.released = Some(u64::MAX);
    let err = encode(&h, &Message::Data(&[]), &mut buf).unwrap_err();
    assert_eq!(err, WireError::SentinelValue { offset: 40 });
    assert!(err.to_string().starts_with("released is u64::MAX"));
}

#[test]
fn error_buffer_too_small() {
    let msg = Message::Data(&[1.0, 2.0]);
    let needed = encoded_len(&msg);
    assert_eq!(needed, 64);
    let mut buf = [0u8; 64];
    for got in 0..needed {
        assert_eq!(
            encode(&header(), &msg, &mut buf[..got]),
            Err(WireError::BufferTooSmall { needed, got })
        );
    }
    assert_eq!(encode(&header(), &msg, &mut buf), Ok(64));
}

#[test]
fn error_destination_too_small() {
    let bytes = data(&[1.0, 2.0, 3.0]);
    let frame = Frame::new_checked(&bytes[..]).unwrap();
    let Payload::Data(ch) = frame.payload() else {
        panic!("not data")
    };
    let mut small = [9.0; 2];
    assert_eq!(
        ch.copy_to(&mut small),
        Err(WireError::DestinationTooSmall { needed: 3, got: 2 })
    );
    assert_eq!(small, [9.0; 2], "untouched on error");
    let mut big = [9.0; 5];
    assert_eq!(ch.copy_to(&mut big), Ok(3));
    assert_eq!(big, [1.0, 2.0, 3.0, 9.0, 9.0]);
}

#[test]
fn encode_reports_errors_in_the_documented_order() {
    let mut tiny = [0u8; 4];
    let mut h = header();
    h.released = Some(u64::MAX);
    // Too many channels beats everything.
    assert_eq!(
        encode(&h, &Message::Data(&[f64::NAN; 300]), &mut tiny),
        Err(WireError::TooManyChannels(300))
    );
    // Then the sentinel, then the buffer, then the values.
    assert_eq!(
        encode(&h, &Message::Data(&[f64::NAN]), &mut tiny),
        Err(WireError::SentinelValue { offset: 40 })
    );
    assert_eq!(
        encode(&header(), &Message::Data(&[f64::NAN]), &mut tiny),
        Err(WireError::BufferTooSmall { needed: 56, got: 4 })
    );
}

#[test]
fn channels_view() {
    let bytes = data(&[1.5, -2.0, 0.25]);
    let frame = Frame::new_checked(&bytes[..]).unwrap();
    let Payload::Data(ch) = frame.payload() else {
        panic!("not data")
    };
    assert_eq!(ch.len(), 3);
    assert!(!ch.is_empty());
    assert_eq!(ch.get(0), Some(1.5));
    assert_eq!(ch.get(2), Some(0.25));
    assert_eq!(ch.get(3), None);
    assert_eq!(ch.get(usize::MAX), None);
    assert_eq!(ch.iter().len(), 3);
    assert_eq!(ch.iter().rev().collect::<Vec<_>>(), [0.25, -2.0, 1.5]);
    assert_eq!(ch.iter().nth(1), Some(-2.0));
    assert_eq!(ch.into_iter().sum::<f64>(), -0.25);
    assert_eq!(ch.as_bytes(), &bytes[48..]);
    assert_eq!(format!("{ch:?}"), "[1.5, -2.0, 0.25]");
    assert!(Channels::default().is_empty());
}

/// Every code converts to its enum and back unchanged, and a known one
/// never to `Unknown`: the enums do not alter a byte of the wire.
#[test]
fn codes_round_trip_and_know_their_variants() {
    for code in 0..=u16::MAX {
        let reason = CloseReason::from(code);
        assert_eq!(u16::from(reason), code);
        assert_eq!(
            matches!(reason, CloseReason::Unknown(_)),
            code > 17,
            "{code}"
        );
        assert_eq!(reason.name() == "unknown", code > 17, "{code}");
    }
    for code in 0..=u8::MAX {
        let (op, mode, underflow) = (
            ControlOp::from(code),
            ModeCode::from(code),
            UnderflowCode::from(code),
        );
        assert_eq!(
            [u8::from(op), u8::from(mode), u8::from(underflow)],
            [code; 3]
        );
        assert_eq!(
            matches!(op, ControlOp::Unknown(_)),
            !(1..=7).contains(&code)
        );
        assert_eq!(matches!(mode, ModeCode::Unknown(_)), code > 1);
        assert_eq!(matches!(underflow, UnderflowCode::Unknown(_)), code > 1);
    }
    assert_eq!(CloseReason::from(9), CloseReason::Busy);
    assert_eq!(ControlOp::from(3), ControlOp::Resume);
    assert_eq!(ModeCode::from(1), ModeCode::PaperDynamic);
    assert_eq!(UnderflowCode::from(1), UnderflowCode::DropLate);
}

#[test]
fn unknown_close_reasons_are_valid() {
    let unknown = Close {
        reason: CloseReason::Unknown(0xbeef),
    };
    let bytes = frame_bytes(&Message::Close(unknown));
    assert_eq!(bytes[48..50], [0xef, 0xbe]);
    let frame = Frame::new_checked(&bytes[..]).unwrap();
    assert_eq!(frame.payload(), Payload::Close(unknown));
    assert_eq!(unknown.to_string(), "unknown (48879)");
    assert_eq!(
        Close {
            reason: CloseReason::WidthMismatch
        }
        .to_string(),
        "width mismatch (3)"
    );
}

#[test]
fn frame_works_over_owned_and_borrowed_buffers() {
    let bytes = frame_bytes(&Message::Hello(hello()));
    let mut array = [0u8; 80];
    array.copy_from_slice(&bytes);
    let owned = Frame::new_checked(bytes.clone()).unwrap();
    let arr = Frame::new_checked(array).unwrap();
    assert_eq!(owned.payload(), arr.payload());
    assert_eq!(owned.into_inner(), bytes);
    let debug = format!("{arr:?}");
    assert!(
        debug.starts_with("Frame { header: Header { seq: 9"),
        "{debug}"
    );
}

#[test]
fn every_error_has_a_message() {
    let errors = [
        WireError::Truncated { needed: 4, got: 1 },
        WireError::LengthOutOfRange(3),
        WireError::LengthMismatch {
            field: 48,
            actual: 50,
        },
        WireError::UnsupportedVersion(3),
        WireError::UnknownKind(9),
        WireError::BadSeat(3),
        WireError::ReservedNotZero { offset: 51 },
        WireError::BadPayloadLength {
            kind: Kind::Data,
            len: 3,
        },
        WireError::BadPayloadLength {
            kind: Kind::Hello,
            len: 3,
        },
        WireError::TooManyChannels(300),
        WireError::NonFinite { index: 4 },
        WireError::BadRole(5),
        WireError::ZeroPeriod,
        WireError::BadRegulationName { offset: 81 },
        WireError::ZeroControlOp,
        WireError::ZeroToken,
        WireError::HoldWithoutEcho,
        WireError::SentinelValue { offset: 24 },
        WireError::BufferTooSmall { needed: 64, got: 8 },
        WireError::DestinationTooSmall { needed: 8, got: 2 },
    ];
    for e in errors {
        let msg = e.to_string();
        assert!(!msg.is_empty());
        let _: &dyn core::error::Error = &e;
        if e != WireError::UnsupportedVersion(3) {
            assert_eq!(e.close_reason(), CloseReason::ProtocolError);
        }
    }
    assert_eq!(
        WireError::BadPayloadLength {
            kind: Kind::Hello,
            len: 3
        }
        .to_string(),
        "Hello payload is 3 bytes; it must be 32 to 64 (32 fixed, then the regulation's \
         name, at most 32 bytes)"
    );
}

#[test]
fn a_tls_record_where_a_frame_was_expected_is_named_in_the_error() {
    // A TLS alert record (a TLS server answering a plain Hello) and a
    // ClientHello's record header, read as a length prefix.
    for header in [[0x15, 0x03, 0x03, 0x00], [0x16, 0x03, 0x01, 0x02]] {
        let e = frame_len(&header).unwrap_err();
        assert!(e.to_string().contains("the peer speaks TLS"), "{e}");
    }
    // Other garbage is not taken for TLS.
    let e = frame_len(b"GET ").unwrap_err();
    assert!(!e.to_string().contains("TLS"), "{e}");
}

#[test]
fn debug_forms_never_show_a_session_token() {
    let token: u64 = 0x5eed_1234_abcd_9876;
    let secret = [
        std::format!("{token}"),
        std::format!("{token:x}"),
        std::format!("{token:#x}"),
    ];
    let mut h = hello();
    h.session = token;
    let b = bundle_bytes(token);
    let frames = [
        frame_bytes(&Message::Hello(h)),
        frame_bytes(&Message::Token(Token { session: token })),
        b,
    ];
    for bytes in &frames {
        let frame = Frame::new_checked(&bytes[..]).unwrap();
        let shown = std::format!("{frame:?} {:?}", frame.payload());
        assert!(shown.contains("<token>"), "{shown}");
        for s in &secret {
            assert!(!shown.contains(s.as_str()), "{shown}");
        }
    }
    // A stream's Hello says it has none.
    let stream = Hello {
        seat: crate::wire::Seat::Control,
        session: 0,
        ..hello()
    };
    assert!(std::format!("{stream:?}").contains("session: 0"));
}

fn bundle_bytes(session: u64) -> Vec<u8> {
    frame_bytes(&Message::Bundle {
        session,
        repeat: 0,
        missed: 0,
        newest: &[1.0],
        older: &[],
    })
}

/// `hello()` naming `name`, as a frame.
fn named_hello(name: &str) -> Vec<u8> {
    frame_bytes(&Message::Hello(Hello {
        regulation: RegulationName::new(name).unwrap(),
        ..hello()
    }))
}

/// `bytes` (a Hello frame) with `name` in place of its regulation's name,
/// the length field set to match.
fn with_name_bytes(bytes: &[u8], name: &[u8]) -> Vec<u8> {
    let mut out = bytes[..HEADER_LEN + Hello::LEN].to_vec();
    out.extend_from_slice(name);
    let len = u32::try_from(out.len()).unwrap();
    out[..4].copy_from_slice(&len.to_le_bytes());
    out
}

#[test]
fn a_hello_carries_the_regulation_s_name_after_its_fixed_part() {
    let bytes = named_hello("adaptive:0.1:1");
    assert_eq!(bytes.len(), HEADER_LEN + 32 + 14);
    assert_eq!(&bytes[80..], b"adaptive:0.1:1");
    let Payload::Hello(h) = Frame::new_checked(&bytes[..]).unwrap().payload() else {
        panic!("a Hello");
    };
    assert_eq!(h.regulation.as_str(), "adaptive:0.1:1");
    assert_eq!(
        h,
        Hello {
            regulation: h.regulation,
            ..hello()
        }
    );
    assert!(
        format!("{h:?}").contains("regulation: \"adaptive:0.1:1\""),
        "{h:?}"
    );
    // A sender that does not say sends the fixed part alone.
    let bare = frame_bytes(&Message::Hello(hello()));
    assert_eq!(bare.len(), HEADER_LEN + 32);
    let Payload::Hello(h) = Frame::new_checked(&bare[..]).unwrap().payload() else {
        panic!("a Hello");
    };
    assert!(h.regulation.is_empty());
    assert_eq!(h.regulation, RegulationName::NONE);
    // The longest name fits.
    let longest = "x".repeat(RegulationName::MAX_LEN);
    assert_eq!(named_hello(&longest).len(), HEADER_LEN + Hello::MAX_LEN);
}

#[test]
fn a_hello_s_regulation_name_is_printable_ascii_and_bounded() {
    let good = named_hello("fixed:200");
    for (name, offset) in [(&b"fixed\n200"[..], 85), (b"\x7f", 80), (b"ab\xc3\xa9", 82)] {
        assert_eq!(
            decode(&with_name_bytes(&good, name)),
            Err(WireError::BadRegulationName { offset })
        );
    }
    let long = with_name_bytes(&good, &[b'x'; 33]);
    assert_eq!(
        decode(&long),
        Err(WireError::BadPayloadLength {
            kind: Kind::Hello,
            len: 65
        })
    );
    let mut short = good[..HEADER_LEN + 31].to_vec();
    short[..4].copy_from_slice(&79u32.to_le_bytes());
    assert_eq!(
        decode(&short),
        Err(WireError::BadPayloadLength {
            kind: Kind::Hello,
            len: 31
        })
    );
    // The payload's size is checked before its fields, the name after them.
    let both = with(with_name_bytes(&good, b"\n"), 48, 7);
    assert_eq!(decode(&both), Err(WireError::BadRole(7)));
    assert_eq!(
        RegulationName::new("tab\there"),
        Err(WireError::BadRegulationName { offset: 83 })
    );
    assert_eq!(
        RegulationName::new(&"x".repeat(33)),
        Err(WireError::BadPayloadLength {
            kind: Kind::Hello,
            len: 65
        })
    );
}

#[test]
fn a_regulation_name_made_lossy_fits_the_wire() {
    // An application's own playout may name itself anyhow.
    assert_eq!(RegulationName::lossy("mine\u{e9}\n").as_str(), "mine??");
    let long = "y".repeat(60);
    assert_eq!(RegulationName::lossy(&long).as_str(), &long[..32]);
    assert_eq!(RegulationName::lossy("").as_str(), "");
    assert_eq!(RegulationName::lossy("adaptive").to_string(), "adaptive");
}
