//! A base whose remote dies and comes back, in simulated time: the first
//! session ends when its connection drops, a second one starts two seconds
//! later with fresh endpoints, and [`Sessions`] keeps what the base's
//! application sees whole across them.

#[allow(unused_imports)]
use std::{boxed::Box, vec, vec::Vec};

use crate::endpoint::{Config, Endpoint, Event, LinkError, Status};
use crate::pair::{Pair, World};
use crate::reconnect::Sessions;
use crate::storage::Heap;
use crate::time::{Duration, Instant};
use crate::wire::Role;

const T: Duration = Duration::from_millis(10);
const ONE_WAY: Duration = Duration::from_millis(5);

fn config(role: Role) -> Config {
    let mut c = Config::new(role).with_width(1);
    c.period = T;
    c
}

/// The base's application across sessions, on one clock: a session's
/// world time plus `offset`.
struct App {
    sessions: Sessions,
    offset: Duration,
    /// (session, sequence the application saw, when).
    seen: Vec<(u32, u64, Instant)>,
    outages: Vec<Duration>,
    k: f64,
}

impl World<Heap> for App {
    type Error = LinkError;

    fn arrival(&mut self, _: Role, sent: Instant, _: &[u8]) -> Option<Instant> {
        Some(sent + ONE_WAY)
    }

    fn event(
        &mut self,
        side: Role,
        ep: &mut Endpoint<Heap>,
        now: Instant,
        event: Event<Box<[f64]>>,
    ) -> Result<(), LinkError> {
        let at = now + self.offset;
        match (side, event) {
            (Role::Remote, Event::Released(r)) => ep.set_sample(&[r.values()[0]])?,
            (Role::Base, Event::Released(r)) => {
                let session = self.sessions.session();
                let fresh = r.status == Status::Fresh;
                if let Some(seq) = self.sessions.admit(session, r.seq, fresh)
                    && fresh
                {
                    self.seen.push((session, seq, at));
                }
                self.k += 1.0;
                ep.set_sample(&[self.k])?;
            }
            (Role::Base, Event::Started { .. }) => {
                self.outages.extend(self.sessions.restored(at));
            }
            _ => {}
        }
        Ok(())
    }

    fn failed(&mut self, _: Role, _: Instant, error: LinkError) -> Result<(), LinkError> {
        Err(error)
    }
}

fn pair(app: App) -> Pair<Heap, App> {
    let base = Endpoint::new(config(Role::Base), Instant::ZERO).unwrap();
    let remote = Endpoint::new(config(Role::Remote), Instant::ZERO).unwrap();
    Pair::new(base, remote, app)
}

#[test]
fn a_restarted_remote_gives_a_second_session_that_continues_the_sequence() {
    let lost_at = Instant::from_millis(3000);
    let back_after = Duration::from_secs(2);
    let mut first = pair(App {
        sessions: Sessions::new(),
        offset: Duration::ZERO,
        seen: vec![],
        outages: vec![],
        k: 0.0,
    });
    first.run_until(lost_at).unwrap();
    // The remote's process dies: what it had sent is lost with it, and
    // the base's driver finds the connection gone.
    let _ = first.drop_in_flight(Role::Remote);
    let (mut base, _, mut app) = first.into_parts();
    base.abort(LinkError::Disconnected);
    let mut closed = false;
    while let Some(e) = base.poll_event() {
        assert!(!matches!(e, Event::Released(_)), "a release after the loss");
        closed |= matches!(
            e,
            Event::Closed {
                error: Some(LinkError::Disconnected)
            }
        );
    }
    assert!(closed);
    assert!(app.sessions.lost(lost_at));
    let first_session = app.seen.len();
    assert!(first_session > 200, "{first_session} releases");

    // Two seconds later both sides start afresh: a new handshake, a new
    // initialization pattern, sequence numbers from zero.
    app.offset = lost_at - Instant::ZERO + back_after;
    let resumed = app.sessions.resumed();
    let mut second = pair(app);
    second.run_until(Instant::from_millis(3000)).unwrap();
    let (_, _, mut app) = second.into_parts();

    // The application saw one rising sequence: nothing twice, nothing out
    // of order, nothing of the first session after the second started.
    assert!(app.seen.len() > first_session + 200);
    assert!(app.seen.windows(2).all(|w| w[0].1 < w[1].1), "not rising");
    let restart = lost_at + back_after;
    for &(session, _, at) in &app.seen {
        assert_eq!(session == resumed, at >= restart, "{session} at {at:?}");
    }
    // A release of the first session offered now is refused and counted.
    let last = app.seen.last().unwrap().1;
    assert_eq!(app.sessions.admit(0, last + 1, true), None);
    assert_eq!(app.sessions.stats().stale, 1);

    // The outage: from the loss to the second session's start, the two
    // seconds away and its initialization pattern (ten round trips and
    // the handshake, well under a second at 10 ms).
    assert_eq!(app.outages.len(), 1, "{:?}", app.outages);
    let outage = app.outages[0];
    assert!(
        outage > back_after && outage < back_after + Duration::from_millis(500),
        "{outage:?}"
    );
    let stats = app.sessions.stats();
    assert_eq!(stats.reconnects, 1);
    assert_eq!(stats.outage_total, outage);
}
