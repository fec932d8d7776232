//! Checks the test vectors of `docs/wire.md` against the codec, byte for byte:
//! editing a byte of the document (or the codec) fails this test.

use ndr_core::time::{Duration, Instant};
use ndr_core::wire::{
    Close, CloseReason, Control, ControlOp, Echo, Frame, Header, Hello, Kind, MAX_FRAME_LEN,
    Message, ModeCode, OlderSample, Payload, RegulationName, Role, Seat, Token, UnderflowCode,
    WireError, encode, frame_len,
};

const DOC: &str = include_str!("../docs/wire.md");

/// A fenced block of the document: its info string, its bytes, and the prose before it.
struct Block {
    tag: &'static str,
    bytes: Vec<u8>,
    prose: String,
}

fn blocks() -> Vec<Block> {
    let mut out = Vec::new();
    let mut prose = String::new();
    let mut lines = DOC.lines();
    while let Some(line) = lines.next() {
        let tag = match line.trim_end() {
            "```hex" => "hex",
            "```hex-invalid" => "hex-invalid",
            other => {
                // Skip other fenced blocks whole, so their content is not taken for prose.
                if other.starts_with("```") {
                    for inner in lines.by_ref() {
                        if inner.trim_end() == "```" {
                            break;
                        }
                    }
                } else {
                    prose.push_str(line);
                    prose.push('\n');
                }
                continue;
            }
        };
        let mut bytes = Vec::new();
        let mut closed = false;
        for inner in lines.by_ref() {
            if inner.trim_end() == "```" {
                closed = true;
                break;
            }
            for token in inner.split_whitespace() {
                assert_eq!(token.len(), 2, "hex token {token:?} is not one byte");
                bytes.push(u8::from_str_radix(token, 16).expect("hex byte"));
            }
        }
        assert!(closed, "unterminated ```{tag} block");
        out.push(Block {
            tag,
            bytes,
            prose: std::mem::take(&mut prose),
        });
    }
    out
}

const NONE: Option<Echo> = None;

/// The layout of vectors 4 and 5 (§3.5).
const LAYOUT: u64 = 0x5954_6583_3bec_ef95;

fn echo(sent_at: u64, hold: u64) -> Option<Echo> {
    Some(Echo {
        sent_at: Instant::from_nanos(sent_at),
        hold: Duration::from_nanos(hold),
    })
}

fn header(seq: u64, sent_at: u64, echo: Option<Echo>, released: Option<u64>) -> Header {
    Header {
        term: 0,
        seq,
        sent_at: Instant::from_nanos(sent_at),
        echo,
        released,
    }
}

/// The frames of §8.1, in document order.
fn valid() -> Vec<(Header, Message<'static>)> {
    vec![
        (
            header(42, 1_500_000_000, echo(1_300_000_000, 2_500_000), Some(40)),
            Message::Data(&[1.5, -0.25, 100.0]),
        ),
        (header(0, 250_000, NONE, None), Message::Data(&[0.0, 3.25])),
        (
            header(7, 1_750_000_000, echo(1_700_000_000, 0), Some(0)),
            Message::Data(&[]),
        ),
        (
            header(0, 1_000, NONE, None),
            Message::Hello(Hello {
                seat: Seat::Control,
                role: Role::Base,
                mode: ModeCode::PaperDynamic,
                underflow: UnderflowCode::Hold,
                command_width: 3,
                state_width: 6,
                period: Duration::from_millis(200),
                layout: LAYOUT,
                session: 0,
                regulation: RegulationName::NONE,
            }),
        ),
        (
            header(0, 5_000_000, echo(1_000, 150_000), None),
            Message::Hello(Hello {
                seat: Seat::Control,
                role: Role::Remote,
                mode: ModeCode::PaperDynamic,
                underflow: UnderflowCode::Hold,
                command_width: 3,
                state_width: 6,
                period: Duration::from_millis(200),
                layout: LAYOUT,
                session: 0,
                regulation: RegulationName::NONE,
            }),
        ),
        (
            header(
                1200,
                240_000_000_000,
                echo(239_800_000_000, 1_000_000),
                Some(1195),
            ),
            Message::Control(Control {
                op: ControlOp::Resume,
                ns: 4,
                period: Duration::from_millis(50),
            }),
        ),
        (
            header(1, 2_000_000, echo(5_000_000, 500_000), None),
            Message::Close(Close {
                reason: CloseReason::PeriodMismatch,
            }),
        ),
        (
            header(42, 1_500_000_000, echo(1_300_000_000, 2_500_000), Some(40)),
            Message::Bundle {
                session: 0x5555_6666_7777_8888,
                repeat: 1,
                missed: 7,
                newest: &[1.5, -0.25],
                older: &OLDER,
            },
        ),
        (
            header(
                1300,
                260_000_000_000,
                echo(259_990_000_000, 2_000_000),
                Some(1290),
            ),
            Message::Token(Token {
                session: 0x0123_4567_89ab_cdef,
            }),
        ),
        (
            header(0, 1_000, NONE, None),
            Message::Hello(Hello {
                seat: Seat::WaitForControl,
                role: Role::Base,
                mode: ModeCode::PaperDynamic,
                underflow: UnderflowCode::Hold,
                command_width: 3,
                state_width: 6,
                period: Duration::from_millis(200),
                layout: LAYOUT,
                session: 0,
                regulation: RegulationName::NONE,
            }),
        ),
        (
            Header {
                term: 3,
                ..header(
                    100,
                    20_000_000_000,
                    echo(19_990_000_000, 1_000_000),
                    Some(98),
                )
            },
            Message::Data(&[0.5, -0.5, 2.0]),
        ),
        (
            Header {
                term: 3,
                ..header(95, 19_000_000_000, echo(18_995_000_000, 500_000), Some(94))
            },
            Message::Control(Control {
                op: ControlOp::Grant,
                ns: 0,
                period: Duration::ZERO,
            }),
        ),
        (
            Header {
                term: 3,
                ..header(
                    2010,
                    20_040_000_000,
                    echo(20_030_000_000, 4_000_000),
                    Some(1998),
                )
            },
            Message::Applied {
                seq: 100,
                sent_at: Instant::from_nanos(20_003_000_000),
                applied_at: Instant::from_nanos(20_040_000_000),
                values: &[0.5, -0.5, 2.0],
            },
        ),
        (
            header(0, 1_000, NONE, None),
            Message::Hello(Hello {
                seat: Seat::Control,
                role: Role::Base,
                mode: ModeCode::PaperStatic,
                underflow: UnderflowCode::Hold,
                command_width: 3,
                state_width: 6,
                period: Duration::from_millis(200),
                layout: LAYOUT,
                session: 0,
                regulation: RegulationName::new("fixed:120").expect("a valid name"),
            }),
        ),
    ]
}

/// The copies of vector 8.
const OLDER: [OlderSample<'static>; 2] = [
    OlderSample {
        seq: 41,
        sent_at: Instant::from_nanos(1_480_000_000),
        released: Some(39),
        values: &[1.25, -0.5],
    },
    OlderSample {
        seq: 40,
        sent_at: Instant::from_nanos(1_460_000_000),
        released: None,
        values: &[1.0, -0.75],
    },
];

/// Encodes with the codec under test.
fn enc(header: &Header, msg: &Message<'_>) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME_LEN];
    let n = encode(header, msg, &mut buf).expect("vector encodes");
    buf[..n].to_vec()
}

/// `bytes` with `new` written at `at`.
fn patch(bytes: &[u8], at: usize, new: &[u8]) -> Vec<u8> {
    let mut out = bytes.to_vec();
    out[at..at + new.len()].copy_from_slice(new);
    out
}

/// `bytes` followed by `extra` zero bytes, with the length field fixed up.
fn padded(bytes: &[u8], extra: usize) -> Vec<u8> {
    let mut out = bytes.to_vec();
    out.resize(bytes.len() + extra, 0);
    let len = u32::try_from(out.len()).unwrap();
    patch(&out, 0, &len.to_le_bytes())
}

/// The strings of §8.2 and their errors, in document order, built from the
/// codec's own encoding of the §8.1 frames (not from the document's bytes).
fn invalid() -> Vec<(Vec<u8>, WireError)> {
    let v: Vec<Vec<u8>> = valid().iter().map(|(h, m)| enc(h, m)).collect();
    let bare = enc(&header(0, 0, NONE, None), &Message::Data(&[]));
    let nan = f64::NAN.to_bits().to_le_bytes();
    assert_eq!(nan, [0, 0, 0, 0, 0, 0, 0xf8, 0x7f], "quiet NaN");
    vec![
        (
            47u32.to_le_bytes().to_vec(),
            WireError::LengthOutOfRange(47),
        ),
        (
            2121u32.to_le_bytes().to_vec(),
            WireError::LengthOutOfRange(2121),
        ),
        (
            v[1][..56].to_vec(),
            WireError::Truncated {
                needed: 64,
                got: 56,
            },
        ),
        (
            [&v[0][..], &[0]].concat(),
            WireError::LengthMismatch {
                field: 72,
                actual: 73,
            },
        ),
        (patch(&v[3], 4, &[1]), WireError::UnsupportedVersion(1)),
        (patch(&bare, 5, &[8]), WireError::UnknownKind(8)),
        (patch(&v[3], 51, &[3]), WireError::BadSeat(3)),
        (patch(&v[1], 32, &[0x10]), WireError::HoldWithoutEcho),
        (
            padded(&enc(&header(3, 0, NONE, None), &Message::Data(&[1.0])), 4),
            WireError::BadPayloadLength {
                kind: Kind::Data,
                len: 12,
            },
        ),
        (patch(&v[0], 56, &nan), WireError::NonFinite { index: 1 }),
        (patch(&v[3], 48, &[2]), WireError::BadRole(2)),
        (
            patch(&v[5], 49, &[1]),
            WireError::ReservedNotZero { offset: 49 },
        ),
        (patch(&v[3], 56, &[0; 8]), WireError::ZeroPeriod),
        (patch(&v[5], 48, &[0]), WireError::ZeroControlOp),
        (
            padded(
                &enc(
                    &header(2, 0, NONE, None),
                    &Message::Close(Close {
                        reason: CloseReason::Normal,
                    }),
                ),
                8,
            ),
            WireError::BadPayloadLength {
                kind: Kind::Close,
                len: 16,
            },
        ),
        (
            patch(&v[6], 50, &[0xff]),
            WireError::ReservedNotZero { offset: 50 },
        ),
        (
            patch(&v[3], 54, &300u16.to_le_bytes()),
            WireError::WidthOutOfRange {
                width: 300,
                offset: 54,
            },
        ),
        (patch(&v[7], 56, &[0]), WireError::BadBundleCount(0)),
        (
            patch(&v[7], 80, &42u64.to_le_bytes()),
            WireError::BundleOrder { index: 1 },
        ),
        (patch(&v[8], 48, &[0; 8]), WireError::ZeroToken),
        (
            patch(&v[13], 85, b"\n"),
            WireError::BadRegulationName { offset: 85 },
        ),
    ]
}

fn assert_payload_matches(payload: Payload<'_>, msg: &Message<'_>) {
    match (payload, msg) {
        (Payload::Data(ch), Message::Data(values)) => {
            let got: Vec<f64> = ch.iter().collect();
            assert_eq!(got.len(), values.len());
            for (g, v) in got.iter().zip(values.iter()) {
                assert_eq!(g.to_bits(), v.to_bits());
            }
        }
        (Payload::Hello(h), Message::Hello(m)) => assert_eq!(h, *m),
        (Payload::Control(c), Message::Control(m)) => assert_eq!(c, *m),
        (Payload::Close(c), Message::Close(m)) => assert_eq!(c, *m),
        (Payload::Token(t), Message::Token(m)) => assert_eq!(t, *m),
        (
            Payload::Applied(a),
            Message::Applied {
                seq,
                sent_at,
                applied_at,
                values,
            },
        ) => {
            assert_eq!(
                (a.seq, a.sent_at, a.applied_at),
                (*seq, *sent_at, *applied_at)
            );
            assert!(a.values.iter().eq(values.iter().copied()));
        }
        (
            Payload::Bundle(b),
            Message::Bundle {
                session,
                repeat,
                missed,
                newest,
                older,
            },
        ) => {
            assert_eq!((b.session(), b.count()), (*session, older.len() + 1));
            assert_eq!((b.repeat(), b.missed()), (*repeat, *missed));
            assert_eq!(b.newest().iter().collect::<Vec<_>>(), newest.to_vec());
            for (got, want) in b.older().zip(older.iter()) {
                assert_eq!(
                    (got.seq, got.sent_at, got.released),
                    (want.seq, want.sent_at, want.released)
                );
                assert_eq!(got.values.iter().collect::<Vec<_>>(), want.values.to_vec());
            }
        }
        (p, m) => panic!("decoded {p:?}, expected {m:?}"),
    }
}

#[test]
fn doc_has_the_expected_blocks() {
    let blocks = blocks();
    let n_valid = blocks.iter().filter(|b| b.tag == "hex").count();
    let n_invalid = blocks.iter().filter(|b| b.tag == "hex-invalid").count();
    assert_eq!(n_valid, valid().len(), "```hex blocks in docs/wire.md");
    assert_eq!(
        n_invalid,
        invalid().len(),
        "```hex-invalid blocks in docs/wire.md"
    );
}

#[test]
fn valid_vectors_encode_and_decode_exactly() {
    let docs: Vec<Block> = blocks().into_iter().filter(|b| b.tag == "hex").collect();
    assert_eq!(docs.len(), valid().len());
    for (i, (block, (header, msg))) in docs.iter().zip(valid()).enumerate() {
        let vector = i + 1;
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = encode(&header, &msg, &mut buf).expect("vector encodes");
        assert_eq!(
            &buf[..n],
            &block.bytes[..],
            "vector {vector}: encoding differs from docs/wire.md"
        );

        assert_eq!(frame_len(&block.bytes), Ok(Some(block.bytes.len())));
        let frame = Frame::new_checked(&block.bytes[..]).expect("vector decodes");
        assert_eq!(frame.kind(), msg.kind(), "vector {vector}");
        assert_eq!(frame.header(), header, "vector {vector}");
        assert_eq!(frame.seq(), header.seq);
        assert_eq!(frame.sent_at(), header.sent_at);
        assert_eq!(frame.echo(), header.echo);
        assert_eq!(frame.released(), header.released);
        assert_payload_matches(frame.payload(), &msg);
    }
}

#[test]
fn invalid_vectors_fail_with_the_documented_error() {
    let docs: Vec<Block> = blocks()
        .into_iter()
        .filter(|b| b.tag == "hex-invalid")
        .collect();
    assert_eq!(docs.len(), invalid().len());
    for (i, (block, (bytes, expected))) in docs.iter().zip(invalid()).enumerate() {
        let vector = i + 1;
        assert_eq!(
            block.bytes, bytes,
            "invalid vector {vector}: bytes differ from docs/wire.md"
        );
        assert_eq!(
            Frame::new_checked(&block.bytes[..]).map(|f| f.header()),
            Err(expected),
            "invalid vector {vector}"
        );
        let named = format!("`{expected:?}`");
        assert!(
            block.prose.contains(&named),
            "invalid vector {vector}: the text before it should name {named}"
        );
    }
}

#[test]
fn invalid_length_prefixes_are_caught_by_frame_len() {
    let docs: Vec<Block> = blocks()
        .into_iter()
        .filter(|b| b.tag == "hex-invalid")
        .collect();
    assert_eq!(
        frame_len(&docs[0].bytes),
        Err(WireError::LengthOutOfRange(47))
    );
    assert_eq!(
        frame_len(&docs[1].bytes),
        Err(WireError::LengthOutOfRange(2121))
    );
}
