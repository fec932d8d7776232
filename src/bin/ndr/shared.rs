//! `ndr remote --observers N`: one robot shared by several bases at once.
//!
//! The listener's floor decides who holds control and fences the others'
//! commands; this module is the robot's thread: it drives the plant with
//! what the controlling link releases, holds it between terms, and sends
//! its state on every link, the observers' included.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::Mutex;
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::Duration as StdDuration;

use ndr::core::endpoint::{Event, LinkError};
use ndr::net::metrics::WatchId;
use ndr::net::{Link, LinkStats, NetError};
use serde::Serialize;

use crate::robot::{Drive, DriveSpec, SessionEnd};
use crate::signals::Stop;

/// One base's session with the shared robot, as the report gives it.
#[derive(Serialize)]
pub struct Session {
    pub peer: SocketAddr,
    /// `controller` if it held control at some point, else `observer`.
    pub role: &'static str,
    /// The terms it held control in.
    pub terms: Vec<u16>,
    /// Its commands the robot applied.
    pub commands_applied: u64,
    /// Its commands the link handed the robot after its term had ended
    /// (the core fences them: always 0; the robot drops them if not).
    pub commands_after_term: u64,
    /// Its commands released before the robot saw its grant: not applied.
    pub commands_before_robot: u64,
    /// What its link refused, by the link's final counters.
    pub commands_refused_stale_term: u64,
    pub commands_refused_observer: u64,
    pub commands_before_grant: u64,
    pub ok: bool,
    pub end: String,
}

/// Sessions a report keeps: a remote that serves for days keeps the last.
const SESSIONS_KEPT: usize = 256;

/// What the robot did over every session.
#[derive(Default)]
pub struct Served {
    /// The last [`SESSIONS_KEPT`] sessions, oldest first.
    pub sessions: std::collections::VecDeque<Session>,
    /// Sessions left out of `sessions` (the oldest).
    pub sessions_dropped: u64,
    /// Over every session, kept or not: [`Session`]'s counters.
    totals: Totals,
    /// Commands applied in each term.
    pub applied_by_term: BTreeMap<u16, u64>,
    /// Commands of a term other than the robot's latest: never applied.
    pub commands_after_term: u64,
}

struct Live {
    link: Link,
    peer: SocketAddr,
    /// Its figures on the `--metrics` page, while it lasts.
    watched: Option<WatchId>,
    terms: Vec<u16>,
    applied: u64,
    after_term: u64,
    early: u64,
}

impl Live {
    fn new(mut link: Link, figures: &Figures) -> Live {
        let peer = link.peer_addr();
        eprintln!("ndr remote: base {peer}: handshake done, running the initialization pattern");
        crate::args::record::attach(figures.recorder, &mut link);
        let watched = figures.served.watch_link(
            peer,
            ndr::core::wire::Role::Remote,
            figures.transport,
            &link.sender(),
        );
        Live {
            peer,
            watched,
            link,
            terms: Vec::new(),
            applied: 0,
            after_term: 0,
            early: 0,
        }
    }
}

#[derive(Default, Clone, Copy)]
struct Totals {
    applied: u64,
    refused_stale_term: u64,
    refused_observer: u64,
    before_grant: u64,
}

impl Served {
    /// Keeps `session`, leaving the oldest out past [`SESSIONS_KEPT`].
    pub fn push(&mut self, session: Session) {
        self.totals.applied += session.commands_applied;
        self.totals.refused_stale_term += session.commands_refused_stale_term;
        self.totals.refused_observer += session.commands_refused_observer;
        self.totals.before_grant += session.commands_before_grant;
        if self.sessions.len() == SESSIONS_KEPT {
            self.sessions.pop_front();
            self.sessions_dropped += 1;
        }
        self.sessions.push_back(session);
    }
}

/// Where each link's figures go: the `--metrics` page (labelled with the
/// transport the links run on), the `--record`ing (every link, numbered
/// in the order the bases came), and (`ndr demo`) the controller's link's
/// latest counters.
pub struct Figures<'a> {
    pub served: &'a crate::metrics::Served,
    pub transport: ndr::net::Transport,
    pub recorder: Option<&'a ndr::net::Recorder>,
    pub controller_stats: Option<&'a Mutex<Option<LinkStats>>>,
}

impl Figures<'_> {
    fn publish(&self, stats: Option<LinkStats>) {
        if let Some(m) = self.controller_stats {
            *m.lock().unwrap_or_else(std::sync::PoisonError::into_inner) = stats;
        }
    }
}

/// Drives the robot for every link that comes on `links` until `stop`
/// (or, with `once`, until the last base has gone after at least one
/// came); what it served.
pub fn robot(
    links: &Receiver<Link>,
    spec: DriveSpec,
    stop: &Stop,
    once: bool,
    figures: &Figures,
) -> Result<Served, String> {
    let period = StdDuration::from_secs_f64(spec.period.as_secs_f64());
    let mut drive = Drive::new(spec)?;
    // No base holds control before the first grant.
    drive.holding = true;
    let mut live: Vec<Live> = Vec::new();
    let mut served = Served::default();
    let mut came = false;
    // The robot's term: the latest granted on any link, and who holds it.
    let mut term = 0_u16;
    let mut controller: Option<SocketAddr> = None;
    let mut held_commands = vec![0.0; drive.axes()];
    while !stop.is_set() {
        // New links; with none to serve, wait a period for one.
        let wait = if live.is_empty() {
            period
        } else {
            StdDuration::ZERO
        };
        match links.recv_timeout(wait) {
            Ok(link) => {
                came = true;
                live.push(Live::new(link, figures));
                while let Ok(link) = links.try_recv() {
                    live.push(Live::new(link, figures));
                }
            }
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) if live.is_empty() => break,
            Err(RecvTimeoutError::Disconnected) => {}
        }
        if once && came && live.is_empty() {
            break;
        }
        // What each link said about control.
        let mut ended: Vec<(usize, SessionEnd)> = Vec::new();
        for l in &mut live {
            for event in l.link.drain_events() {
                crate::logging::event("remote", &event);
                match event {
                    Event::ControlGranted { term: t } => {
                        l.terms.push(t);
                        if t > term {
                            term = t;
                        }
                        controller = Some(l.peer);
                        eprintln!("ndr remote: base {} holds control (term {t})", l.peer);
                    }
                    Event::ControlYielded { .. } if controller == Some(l.peer) => {
                        controller = None;
                        eprintln!("ndr remote: base {} gave control up", l.peer);
                    }
                    Event::Started { period, .. } => {
                        drive.set_period(period)?;
                    }
                    _ => {}
                }
            }
        }
        // The controller's command (waiting a period for it), else a
        // period's hold.
        let at = controller.and_then(|c| live.iter().position(|l| l.peer == c));
        let mut stepped = false;
        if let Some(c) = at {
            let l = &mut live[c];
            match l.link.recv_timeout(period * 2) {
                Ok(command) if command.term == term => {
                    drive.holding = false;
                    held_commands.copy_from_slice(command.values());
                    l.applied += 1;
                    *served.applied_by_term.entry(term).or_default() += 1;
                    stepped = true;
                }
                Ok(_) => {
                    l.after_term += 1;
                    served.commands_after_term += 1;
                }
                Err(NetError::Timeout) => {}
                Err(NetError::Link(e)) => ended.push((c, SessionEnd::Ended(e))),
                Err(e) => {
                    ended.push((
                        c,
                        SessionEnd::AppFailure(format!("receiving a command failed: {e}")),
                    ));
                }
            }
        } else {
            controller = None;
            drive.holding = true;
            std::thread::sleep(period);
            stepped = true;
        }
        // The others' links release nothing the robot takes: drained, so
        // that their ends show.
        for (i, l) in live.iter_mut().enumerate() {
            if Some(i) == at {
                continue;
            }
            loop {
                match l.link.try_recv() {
                    Ok(Some(s)) if s.status == ndr::core::endpoint::Status::Fresh => {
                        if s.term < term {
                            l.after_term += 1;
                            served.commands_after_term += 1;
                        } else {
                            // Its grant is on its way: the robot takes
                            // commands from the next turn on.
                            l.early += 1;
                        }
                    }
                    Ok(Some(_)) => {}
                    Ok(None) => break,
                    Err(NetError::Link(e)) => {
                        ended.push((i, SessionEnd::Ended(e)));
                        break;
                    }
                    Err(e) => {
                        ended.push((i, SessionEnd::AppFailure(format!("{e}"))));
                        break;
                    }
                }
            }
        }
        if let Some(c) = at {
            figures.publish(live[c].link.stats());
        }
        if stepped {
            let state = drive.step(&held_commands)?.to_vec();
            for (i, l) in live.iter().enumerate() {
                match l.link.send(&state) {
                    Ok(()) => {}
                    Err(NetError::Link(e)) if e.is_fatal() => {
                        ended.push((i, SessionEnd::Ended(e)));
                    }
                    Err(e) => ended.push((
                        i,
                        SessionEnd::AppFailure(format!("the link refused the robot's state: {e}")),
                    )),
                }
            }
        }
        ended.sort_by_key(|e| std::cmp::Reverse(e.0));
        ended.dedup_by_key(|e| e.0);
        for (i, end) in ended {
            let l = live.swap_remove(i);
            if controller == Some(l.peer) {
                controller = None;
            }
            served.push(close(l, end, figures));
        }
    }
    for l in live {
        served.push(close(l, SessionEnd::Stopped, figures));
    }
    Ok(served)
}

/// Closes a session's link; its line on stderr, its entry in the report.
fn close(l: Live, end: SessionEnd, figures: &Figures) -> Session {
    let Live {
        link,
        peer,
        watched,
        terms,
        applied,
        after_term,
        early,
    } = l;
    let failed = matches!(end, SessionEnd::AppFailure(_));
    let mut link = link;
    if failed {
        link.abort();
    }
    let stats = link.close();
    figures.served.unwatch(watched);
    if !terms.is_empty() {
        figures.publish(stats);
    }
    let e = stats.map(|s| s.endpoint).unwrap_or_default();
    let role = if terms.is_empty() {
        "observer"
    } else {
        "controller"
    };
    // An observer's link closed by its base is as good an end as a
    // controller's.
    let ok = end.ok()
        || matches!(
            end,
            SessionEnd::Ended(LinkError::PeerClosed {
                reason: ndr::core::wire::CloseReason::Normal
            })
        );
    eprintln!(
        "ndr remote: base {peer} ({role}, terms {terms:?}): {end}; {applied} commands applied, \
         {} refused as of an ended term",
        e.commands_refused_stale_term
    );
    Session {
        peer,
        role,
        terms,
        commands_applied: applied,
        commands_after_term: after_term,
        commands_before_robot: early,
        commands_refused_stale_term: e.commands_refused_stale_term,
        commands_refused_observer: e.commands_refused_observer,
        commands_before_grant: e.commands_before_grant,
        ok,
        end: end.to_string(),
    }
}

impl Session {
    /// A session of a robot not shared: its base controlled it throughout.
    pub fn alone(
        peer: SocketAddr,
        end: &SessionEnd,
        stats: Option<ndr::net::LinkStats>,
    ) -> Session {
        let e = stats.map(|s| s.endpoint).unwrap_or_default();
        Session {
            peer,
            role: "controller",
            terms: vec![1],
            commands_applied: e.released_fresh,
            commands_after_term: 0,
            commands_before_robot: 0,
            commands_refused_stale_term: e.commands_refused_stale_term,
            commands_refused_observer: e.commands_refused_observer,
            commands_before_grant: e.commands_before_grant,
            ok: end.ok(),
            end: end.to_string(),
        }
    }
}

/// What `ndr remote --json` prints when it stops.
#[derive(Serialize)]
pub struct RemoteReport {
    command: &'static str,
    /// Whether it stopped without failure (the exit status is 0 then).
    ok: bool,
    /// Why it failed, if it did.
    error: Option<String>,
    listen: SocketAddr,
    /// Whether the robot was shared (`--observers`).
    shared: bool,
    /// Times control changed hands.
    handovers: u64,
    /// The most observers served at once.
    observers_max: u64,
    /// Bases refused control (another held it), refused because their
    /// identity may only observe, or because every observer's seat was
    /// taken.
    refused_busy: u64,
    refused_observer_only: u64,
    refused_observers_full: u64,
    /// Every session's link: commands refused as of a term that had ended
    /// (fencing), sent by an observer, or come before the grant.
    commands_refused_stale_term: u64,
    commands_refused_observer: u64,
    commands_before_grant: u64,
    /// Commands the robot applied, in all and in each term (`[term, n]`).
    commands_applied: u64,
    commands_applied_by_term: Vec<(u16, u64)>,
    /// Commands of an ended term handed to the robot: none applied.
    commands_after_term: u64,
    /// Applied commands told to the observers, and notes to the floor
    /// dropped for want of room.
    applied_forwarded: u64,
    notes_dropped: u64,
    /// Each base's session, the last 256; `sessions_dropped` the older.
    sessions: std::collections::VecDeque<Session>,
    sessions_dropped: u64,
}

impl RemoteReport {
    pub fn new(
        listen: SocketAddr,
        listener: &ndr::net::ListenerStats,
        sharing: Option<ndr::net::SharingStats>,
        served: Served,
        error: Option<&str>,
    ) -> RemoteReport {
        let t = served.totals;
        let floor = sharing.map(|s| s.floor).unwrap_or_default();
        RemoteReport {
            command: "remote",
            ok: error.is_none(),
            error: error.map(str::to_owned),
            listen,
            shared: sharing.is_some(),
            handovers: floor.handovers,
            observers_max: floor.observers_max,
            refused_busy: listener.refused_busy,
            refused_observer_only: listener.refused_observer_only,
            refused_observers_full: listener.refused_observers_full,
            commands_refused_stale_term: t.refused_stale_term,
            commands_refused_observer: t.refused_observer,
            commands_before_grant: t.before_grant,
            commands_applied: t.applied,
            commands_applied_by_term: served.applied_by_term.into_iter().collect(),
            commands_after_term: served.commands_after_term,
            applied_forwarded: sharing.map_or(0, |s| s.applied_forwarded),
            notes_dropped: sharing.map_or(0, |s| s.notes_dropped),
            sessions: served.sessions,
            sessions_dropped: served.sessions_dropped,
        }
    }
}
