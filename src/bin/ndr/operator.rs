//! The operator at the base, shared by `demo` and `base`: it follows the
//! signal (or closes a loop on the state), writes the series and shows a
//! live status line.

use std::io::{IsTerminal, Write};
use std::sync::Mutex;
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::core::endpoint::{Event, Status};
use ndr::core::time::Duration;
use ndr::net::{Link, LinkStats, NetError};

use crate::args::RunArgs;
use crate::pauses::{self, LateTicks};
use crate::report::{End, Row, Seating, Series, link_ended};
use crate::tracking::{ControllerKind, Tracker, TrackingSummary};

/// What the operator keeps beside the series, if asked: the late ticks
/// (`ndr demo`), the base's seat at the robot (`ndr base`).
#[derive(Default)]
pub struct Kept<'a> {
    pub late: Option<&'a Mutex<LateTicks>>,
    pub seating: Option<&'a mut Seating>,
}

/// The base: the operator follows the signal until `until`; one row per
/// released state goes to `series`. Returns the base's final counters and
/// how the run ended; the link is closed (or aborted) either way.
pub fn operator(
    mut link: Link,
    run: &RunArgs,
    axes: u16,
    until: StdInstant,
    remote_stats: Option<&Mutex<Option<LinkStats>>>,
    series: &mut Series,
    kept: Kept<'_>,
) -> (Option<LinkStats>, End, Option<TrackingSummary>) {
    let Kept { late, mut seating } = kept;
    let start = StdInstant::now();
    // Made at the first release, at the period the link runs at.
    let mut tracker: Option<Tracker> = None;
    let mut u = 0.0;
    let live = !run.json && std::io::stderr().is_terminal();
    let mut next_status = start;
    let mut command = vec![0.0; usize::from(axes)];
    let mut last_grtt = f64::NAN;
    let mut released = 0_u64;
    let mut end = None;
    loop {
        let now = StdInstant::now();
        if now >= until {
            break;
        }
        let t = start.elapsed().as_secs_f64();
        for (axis, c) in command.iter_mut().enumerate() {
            *c = match run.controller {
                ControllerKind::None => run.signal.value(t, axis),
                // The loop drives the first axis; the others stay at rest.
                _ if axis == 0 => u,
                _ => 0.0,
            };
        }
        match link.send(&command) {
            Ok(()) => {}
            Err(NetError::Link(e)) if e.is_fatal() => {
                end = Some(link_ended(&NetError::Link(e), released));
                break;
            }
            Err(e) => {
                end = Some(End::AppFailure(format!(
                    "the operator's command was refused: {e}"
                )));
                break;
            }
        }
        let wait = (until - now).min(StdDuration::from_millis(500));
        match link.recv_timeout(wait) {
            Ok(s) => {
                released += 1;
                if let Some(seating) = seating.as_deref_mut() {
                    seating.saw(s.term);
                }
                if let Some(g) = s.grtt {
                    last_grtt = g.as_secs_f64();
                }
                let state = s.values().first().copied().unwrap_or(f64::NAN);
                if run.controller != ControllerKind::None {
                    let stepped = match &mut tracker {
                        Some(tr) => tr.tick(state, s.status != Status::Held, s.grtt),
                        None => link
                            .stats()
                            .map(|st| st.period)
                            .ok_or_else(|| "the link released a state before it started".into())
                            .and_then(|p| Tracker::new(run.controller, p))
                            .and_then(|made| {
                                let tr = tracker.insert(made.ok_or("no controller")?);
                                tr.tick(state, s.status != Status::Held, s.grtt)
                            }),
                    };
                    match stepped {
                        Ok(next) => u = next,
                        Err(e) => {
                            end = Some(End::AppFailure(e));
                            break;
                        }
                    }
                }
                pauses::note(late, &link, &s);
                let row = Row {
                    t_s: t,
                    seq: s.seq,
                    held: s.status == Status::Held,
                    grtt_s: s.grtt.map(Duration::as_secs_f64),
                    nrtt_s: link
                        .stats()
                        .and_then(|st| st.last_nrtt)
                        .map(Duration::as_secs_f64),
                    command: command[0],
                    state,
                };
                if let Err(e) = series.push(&row) {
                    end = Some(End::AppFailure(e));
                    break;
                }
            }
            Err(NetError::Timeout) => {}
            Err(e) => {
                end = Some(link_ended(&e, released));
                break;
            }
        }
        for event in link.drain_events() {
            crate::logging::event("base", &event);
            if let (Event::Started { period, .. }, Some(tr)) = (&event, &mut tracker)
                && let Err(e) = tr.set_period(*period)
            {
                end = Some(End::AppFailure(e));
            }
        }
        if end.is_some() {
            break;
        }
        if StdInstant::now() >= next_status {
            next_status += StdDuration::from_millis(250);
            if live {
                status_line(t, link.stats().as_ref(), remote_stats, last_grtt);
            }
        }
    }
    if live {
        eprintln!();
    }
    let end = end.unwrap_or_else(|| {
        if released > 0 {
            return End::Completed;
        }
        // `connect` returns before the handshake: a peer that accepts the
        // connection but never answers shows only here.
        let phase = link.stats().map_or("the handshake", |s| s.phase.name());
        End::NeverConnected(format!(
            "no sample was released in the {} s run (the link was still in {phase}); \
             check that the peer is an ndr remote (or a relay to one) with the same \
             settings, or run longer",
            run.duration_s
        ))
    });
    if matches!(end, End::AppFailure(_)) {
        tracing::error!("base: {end}; ending the link as an application failure");
        link.abort();
    }
    (link.close(), end, tracker.map(|t| t.summary()))
}

fn status_line(
    t: f64,
    base: Option<&LinkStats>,
    remote: Option<&Mutex<Option<LinkStats>>>,
    grtt: f64,
) {
    let remote = remote.and_then(|r| *r.lock().unwrap_or_else(std::sync::PoisonError::into_inner));
    let ms = |d: Option<Duration>| {
        d.map_or("–".to_string(), |d| {
            format!("{:.1} ms", d.as_secs_f64() * 1e3)
        })
    };
    let (nrtt, qb, uf_b, phase) = base.map_or((String::from("–"), 0, 0, "starting"), |s| {
        (
            ms(s.last_nrtt),
            s.queue_len,
            s.endpoint.underflows,
            s.phase.name(),
        )
    });
    let (qr, uf_r) = remote.map_or((0, 0), |s| (s.queue_len, s.endpoint.underflows));
    let grtt = if grtt.is_finite() {
        format!("{:.1} ms", grtt * 1e3)
    } else {
        "–".into()
    };
    eprint!(
        "\r\x1b[2K  t {t:5.1} s · {phase:<12} · NRTT {nrtt:>9} · GRTT {grtt:>9} · queue base {qb:>3} remote {qr:>3} · underflows {} ",
        uf_b + uf_r
    );
    let _ = std::io::stderr().flush();
}
