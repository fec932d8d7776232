//! Replays the session vectors of `docs/wire.md` §10.1 through a remote
//! endpoint: each line's frame, at its arrival time, must give the verdict
//! the document states (editing the document or the checks fails this test).

use ndr_core::endpoint::{Config, Endpoint, Mode};
use ndr_core::playout::Playout;
use ndr_core::storage::Inline;
use ndr_core::time::{Duration, Instant};
use ndr_core::wire::{
    Echo, Header, Hello, MAX_FRAME_LEN, Message, ModeCode, Role, UnderflowCode, encode,
};

const DOC: &str = include_str!("../docs/wire.md");
const T: Duration = Duration::from_millis(200);

/// One line of a session block.
struct Line {
    at: Instant,
    header: Header,
    verdict: String,
}

/// The ```session blocks of the document, in order.
fn sessions() -> Vec<Vec<Line>> {
    let mut out = Vec::new();
    let mut lines = DOC.lines();
    while let Some(line) = lines.next() {
        if line.trim_end() != "```session" {
            continue;
        }
        let mut block = Vec::new();
        for inner in lines.by_ref() {
            let inner = inner.trim();
            if inner == "```" {
                break;
            }
            if inner.starts_with('#') || inner.is_empty() {
                continue;
            }
            let tokens: Vec<&str> = inner.split_whitespace().collect();
            assert!(tokens.len() >= 6, "five fields and a verdict: {inner}");
            let num = |s: &str| s.parse::<u64>().expect("a number");
            let at = Instant::from_nanos(num(tokens[0]));
            let seq = num(tokens[1]);
            let sent_at = Instant::from_nanos(num(tokens[2]));
            let echo = (tokens[3] != "-").then(|| Echo {
                sent_at: Instant::from_nanos(num(tokens[3])),
                hold: Duration::from_nanos(num(tokens[4])),
            });
            // The verdict is the rest of the line (it has spaces).
            let verdict = tokens[5..].join(" ");
            block.push(Line {
                at,
                header: Header {
                    term: 0,
                    seq,
                    sent_at,
                    echo,
                    released: None,
                },
                verdict,
            });
        }
        out.push(block);
    }
    out
}

fn remote() -> Endpoint<Inline<1, 8>> {
    let mut c = Config::paper(Role::Remote);
    c.period = T;
    c.mode = Mode::PaperStatic;
    c.playout = Playout::Fifo;
    Endpoint::new(c, Instant::ZERO).expect("a valid configuration")
}

/// Hands `line`'s frame to `ep` (the first of a session is the base's
/// Hello), then lets it send what it answers, stamped at the arrival.
fn hand(ep: &mut Endpoint<Inline<1, 8>>, line: &Line, first: bool) -> String {
    let hello = Hello {
        seat: ndr_core::wire::Seat::Control,
        role: Role::Base,
        mode: ModeCode::PaperStatic,
        underflow: UnderflowCode::Hold,
        command_width: 1,
        state_width: 1,
        period: T,
        layout: 0,
        session: 0,
        regulation: ndr_core::wire::RegulationName::NONE,
    };
    let msg = if first {
        Message::Hello(hello)
    } else {
        Message::Data(&[])
    };
    let mut buf = [0u8; MAX_FRAME_LEN];
    let n = encode(&line.header, &msg, &mut buf).expect("a vector encodes");
    let verdict = match ep.handle_frame(line.at, &buf[..n]) {
        Ok(()) => "ok".to_string(),
        Err(e) => format!("{e:?}"),
    };
    while let Ok(Some(_)) = ep.poll_transmit(line.at, &mut buf) {}
    verdict
}

#[test]
fn the_documented_sessions_give_their_verdicts() {
    let sessions = sessions();
    assert_eq!(sessions.len(), 4, "four session blocks in §10.1");
    let mut checked = 0;
    for (s, block) in sessions.iter().enumerate() {
        // Each line on a fresh remote, replayed through the `ok` lines before it.
        for (i, line) in block.iter().enumerate() {
            let mut ep = remote();
            let before: Vec<&Line> = block[..i].iter().filter(|l| l.verdict == "ok").collect();
            for (k, b) in before.iter().enumerate() {
                assert_eq!(hand(&mut ep, b, k == 0), "ok", "session {}", s + 1);
            }
            let got = hand(&mut ep, line, before.is_empty());
            assert_eq!(got, line.verdict, "session {}, line {}", s + 1, i + 1);
            checked += 1;
        }
    }
    assert!(checked >= 20, "{checked} lines");
}
