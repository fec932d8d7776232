//! What every regulated link over loopback must show (shared by the plain
//! and the TLS link tests).

use std::time::Duration;

use ndr::core::endpoint::Status;
use ndr::net::{Link, LinkStats};

/// The tests of a file that measures jitter run one at a time: the others'
/// threads, handshakes and hubs would add their own (on two cores, a few
/// frames then miss their tick and the round trip steps by a period).
static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Held for the whole test: the next waits until it ends.
pub fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// What one regulated run over a real link measured.
pub struct Run {
    /// The base's fresh releases, by sequence number.
    pub base_seqs: Vec<u64>,
    /// The remote's.
    pub remote_seqs: Vec<u64>,
    /// The GRTTs the base's fresh releases carried: when each was released
    /// (ns, the base hub's clock) and the GRTT (s).
    pub grtts: Vec<(u64, f64)>,
    /// The base's fresh releases that were one of its commands echoed.
    pub echoed: usize,
    /// Whether the remote's application answers from a thread of its own,
    /// so at the tick after the one that released the command (a release
    /// handler on the hub's thread answers in the same tick).
    pub answers_next_tick: bool,
    pub base: LinkStats,
    /// Where the test has them.
    pub remote: Option<LinkStats>,
}

/// The base's side of a run: 300 ticks of commands `(k, −k, k, −k, …)`
/// (the link's command width), each answered by the next release;
/// `(fresh seqs, GRTTs, echoed)`, `echoed` counting the fresh releases that
/// carried one of the commands back (the remote sends zeros until it has
/// one). A command comes back whole ([`answer`]).
pub fn drive_base(base: &mut Link) -> (Vec<u64>, Vec<(u64, f64)>, usize) {
    let (commands, states) = base.widths();
    let (mut seqs, mut grtts, mut echoed) = (Vec::new(), Vec::new(), 0);
    for k in 1..=300 {
        let command: Vec<f64> = (0..commands).map(|i| alternate(f64::from(k), i)).collect();
        base.send(&command).unwrap();
        let s = base.recv_timeout(Duration::from_secs(5)).unwrap();
        if s.status == Status::Fresh {
            seqs.push(s.seq);
            grtts.extend(s.grtt.map(|g| (s.released_at.as_nanos(), g.as_secs_f64())));
            let v = s.values();
            assert_eq!(v.len(), states);
            let whole = (0..states).all(|i| v[i] == alternate(v[0], i % commands));
            assert!(whole, "a state that is not a command echoed whole: {v:?}");
            if v[0] > 0.0 {
                echoed += 1;
            }
        }
    }
    (seqs, grtts, echoed)
}

/// `k` at even channels, `−k` at odd ones.
fn alternate(k: f64, i: usize) -> f64 {
    if i.is_multiple_of(2) { k } else { -k }
}

/// The remote's answer to `command`: a state of `width` values, channel
/// `i` the command's channel `i mod` its width (the echo, when the widths
/// are equal).
pub fn answer(command: &[f64], width: usize) -> Vec<f64> {
    (0..width)
        .map(|i| {
            command
                .get(i % command.len().max(1))
                .copied()
                .unwrap_or(0.0)
        })
        .collect()
}

/// A run over a connected pair: the remote, on a thread of its own, returns
/// each command it is given (its "plant", [`answer`]), the base drives 300
/// ticks and closes the link.
pub fn echo_run(mut base: Link, mut remote: Link) -> Run {
    let robot = std::thread::spawn(move || {
        let mut seqs = Vec::new();
        let width = remote.widths().0;
        loop {
            // Long past any pause of the host: the base's close ends it.
            match remote.recv_timeout(Duration::from_secs(10)) {
                Ok(s) => {
                    if s.status == Status::Fresh {
                        seqs.push(s.seq);
                    }
                    remote.send(&answer(s.values(), width)).unwrap();
                }
                Err(_) => return (seqs, remote.stats()),
            }
        }
    });
    let (base_seqs, grtts, echoed) = drive_base(&mut base);
    let base = base.close().unwrap();
    let (remote_seqs, remote) = robot.join().unwrap();
    Run {
        base_seqs,
        remote_seqs,
        grtts,
        echoed,
        answers_next_tick: true,
        base,
        remote,
    }
}

/// Sends each of `junk` from `stranger` to the listener's `port`, then,
/// once `remote` has heard from its base, to the base's own socket.
// Only the datagram transports' tests send strays.
#[allow(dead_code)]
pub fn send_to_both_sides(
    stranger: &std::net::UdpSocket,
    port: std::net::SocketAddr,
    remote: &Link,
    junk: &[&[u8]],
) {
    for bytes in junk {
        stranger.send_to(bytes, port).unwrap();
    }
    // The remote learns the base's address from the base's first datagram,
    // which a busy host may hold back: waited for, within a bound.
    let since = std::time::Instant::now();
    let base_at = loop {
        match remote.stats().and_then(|s| s.datagram_peer) {
            Some(at) => break at,
            None if since.elapsed() < Duration::from_secs(5) => {
                std::thread::sleep(Duration::from_millis(10));
            }
            None => panic!("the base's address: none after 5 s"),
        }
    };
    for bytes in junk {
        stranger.send_to(bytes, base_at).unwrap();
    }
}

/// The deadlines the run's hubs woke for 1 ms late or more (their
/// `lateness.missed`): each may cost a sample its fresh release or its
/// round trip, counted.
fn missed(run: &Run) -> usize {
    let sides = std::iter::once(&run.base).chain(&run.remote);
    sides.map(|s| s.lateness.missed).sum::<u64>() as usize
}

/// The samples side `name` counted as lost: over datagrams, those neither a
/// datagram nor a copy nor a repeat brought in time (none on a quiet
/// loopback; a host that holds a hub tens of milliseconds makes some).
fn lost_at(run: &Run, name: &str) -> u64 {
    match name {
        "base" => run.base.endpoint.samples_lost,
        _ => run.remote.map_or(0, |s| s.endpoint.samples_lost),
    }
}

/// Each side released more than 250 fresh samples, each once and in
/// order, with no gap but for the samples its peer's hub, held by the host
/// past its transmit queue, dropped (`tx_dropped`), or it counted as lost.
// Only the datagram transports' tests judge a run this way.
#[allow(dead_code)]
pub fn assert_every_sample_once_in_order(run: &Run) {
    let sent_by = [
        run.remote.map(|s| s.endpoint.tx_dropped),
        Some(run.base.endpoint.tx_dropped),
    ];
    for ((name, seqs), dropped) in [("base", &run.base_seqs), ("remote", &run.remote_seqs)]
        .into_iter()
        .zip(sent_by)
    {
        let floor = 250usize.saturating_sub(2 * missed(run));
        assert!(seqs.len() > floor, "{name}: {}", seqs.len());
        let missing: u64 = seqs.windows(2).map(|w| w[1].saturating_sub(w[0] + 1)).sum();
        let counted = dropped.unwrap_or(0) + lost_at(run, name);
        assert!(
            seqs.windows(2).all(|w| w[1] > w[0]) && missing <= counted,
            "{name}: {missing} missing, {counted} counted: {seqs:?}"
        );
    }
}

/// Both sides' fresh samples came once each and in order, and the base's
/// round trip is constant: at T = 10 ms on loopback with ns = 2, GRTT is
/// 2·ns·T to (2·ns + 2)·T depending on the phase between the two sides'
/// tick grids (a frame read in the same pass as a tick's deadline still
/// counts for that tick), a period more when the remote answers from a
/// thread of its own (the tick after the release).
///
/// One run, judged with margins a shared host cannot break. The host may
/// hold the process, or the kernel's loopback path, for milliseconds: the
/// releases around it are late, past the queue's slack the FIFO's delay
/// steps up by a period (by design, an underflow counted), and a hub held
/// for more ticks than its endpoint queues transmissions for (8) drops the
/// samples of the ticks it missed, counted (`tx_dropped`). So order is
/// checked strictly, completeness but for counted drops, and the GRTT on
/// the schedule: each less the lateness of the release that measured it,
/// at its level (whole periods from the median, held for 10 GRTTs in a row
/// or more, the level changing no more than twice per counted underflow);
/// at most a tenth of them, and two per tick a hub missed, in a briefer
/// excursion or more than 2 ms from the median, the others within 1 ms std.
/// A tick a hub missed (a deadline it woke for 1 ms late or more) may
/// leave one more sample in a queue, or a queue run dry: the level may
/// change once more per tick missed, and sit a period off.
/// That the regulation itself makes the round trip exactly constant is
/// judged in simulated time (`crates/ndr-sim/tests/paper.rs`, the core's
/// `Pair` tests, `python/tests/test_demo.py` for both transports).
pub fn assert_regulated(run: impl FnOnce() -> Run) -> Run {
    let r = run();
    // Each side's fresh releases, and the peer that sent them.
    let sent_by = [
        r.remote.map(|s| s.endpoint.tx_dropped),
        Some(r.base.endpoint.tx_dropped),
    ];
    for ((name, seqs), dropped) in [("base", &r.base_seqs), ("remote", &r.remote_seqs)]
        .into_iter()
        .zip(sent_by)
    {
        let floor = 250usize.saturating_sub(2 * missed(&r));
        assert!(seqs.len() > floor, "{name}: {}", seqs.len());
        // Where a sample went twice or out of order, or went missing,
        // and what each side counted.
        let twice = seqs.windows(2).find(|w| w[1] <= w[0]);
        let missing: u64 = seqs.windows(2).map(|w| w[1].saturating_sub(w[0] + 1)).sum();
        let gap = seqs.windows(2).find(|w| w[1] > w[0] + 1);
        let counted = dropped.is_some_and(|d| d + lost_at(&r, name) >= missing);
        assert!(
            twice.is_none() && (missing == 0 || counted),
            "{name}: repeat at {twice:?}, {missing} missing (first at {gap:?}); base {:?}; \
             remote {:?}",
            r.base,
            r.remote
        );
    }
    let floor = 250usize.saturating_sub(2 * missed(&r));
    assert!(r.echoed > floor, "{} commands echoed", r.echoed);
    assert_constant_grtt(&r);
    r
}

fn assert_constant_grtt(r: &Run) {
    let (mean, std) = grtt_judged(r);
    let sides = || std::iter::once(&r.base).chain(&r.remote);
    let raised: u64 = sides()
        .map(|s| s.endpoint.underflows + s.lateness.missed)
        .sum();
    assert!(
        std <= 1e-3,
        "GRTT std {std} s: {:?}; base {:?}; remote {:?}",
        r.base.endpoint.grtt,
        r.base,
        r.remote
    );
    // The FIFO: 2·ns·T to (2·ns + 2)·T by the grids' phase; a target-delay
    // playout: the delays it holds each way, up to two periods more (each
    // side's release waits for its own tick). A period more when the
    // remote answers from its own thread.
    let period = r.base.period.as_secs_f64();
    let held =
        r.base.endpoint.playout_delay_s + r.remote.map_or(0.0, |s| s.endpoint.playout_delay_s);
    let regulated = if held > 0.0 {
        held
    } else {
        (2 * r.base.ns) as f64 * period
    };
    let from = regulated + f64::from(u8::from(r.answers_next_tick)) * period;
    // Each underflow or tick missed may move the level a period (a queue
    // that ran dry, or one more sample left in it).
    let (from, to) = (
        from - raised as f64 * period,
        from + (2 + raised) as f64 * period,
    );
    assert!(
        (from - 1e-3..=to + 1e-3).contains(&mean),
        "GRTT mean {mean}, expected {from} to {to} (ns {}, delays held {held} s, {raised} \
         underflows and ticks missed)",
        r.base.ns
    );
}

/// The mean and std (s) of the base's round trip in `r`, judged as
/// [`assert_regulated`] does.
pub fn grtt_judged(r: &Run) -> (f64, f64) {
    let all = r.base.endpoint.grtt;
    let floor = 200usize.saturating_sub(2 * missed(r));
    assert!(all.count() as usize > floor, "{all:?}");
    let sides: Vec<&LinkStats> = std::iter::once(&r.base).chain(&r.remote).collect();
    judge_grtts(&r.grtts, &sides)
}

/// The mean and std (s) of GRTTs `(released at, ns of the hub's clock; GRTT,
/// s)` measured by `sides[0]`, `sides` being the link's two ends where the
/// test has them: on the schedule, at their level, less the strays a
/// stalled host makes (asserted to be few).
pub fn judge_grtts(grtts: &[(u64, f64)], sides: &[&LinkStats]) -> (f64, f64) {
    let underflows: u64 = sides.iter().map(|s| s.endpoint.underflows).sum();
    let missed: u64 = sides.iter().map(|s| s.lateness.missed).sum();
    judge_grtts_counted(grtts, sides[0].period.as_nanos(), underflows, missed)
}

/// [`judge_grtts`] for a run whose counters come from elsewhere (a
/// report): the link's period (ns), and the underflows and ticks missed
/// both sides counted.
pub fn judge_grtts_counted(
    grtts: &[(u64, f64)],
    period_ns: u64,
    underflows: u64,
    missed: u64,
) -> (f64, f64) {
    // The callers judge how many there must be.
    assert!(grtts.len() > 20, "{} GRTTs", grtts.len());
    let grtts = on_schedule(grtts, period_ns);
    let mut sorted = grtts.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    // Past the queue's slack the FIFO's delay steps by a period, once per
    // underflow or tick missed at most: each GRTT is judged at its own
    // level, a level being one held for `SETTLED` GRTTs in a row; a shorter
    // excursion is the host's (a hub held past a tick), its GRTTs strays.
    const SETTLED: usize = 10;
    let period = period_ns as f64 * 1e-9;
    let level = |g: f64| ((g - median) / period).round();
    // Runs of one level: (level, GRTTs in a row).
    let mut runs: Vec<(f64, usize)> = Vec::new();
    for &g in &grtts {
        match runs.last_mut() {
            Some((l, n)) if *l == level(g) => *n += 1,
            _ => runs.push((level(g), 1)),
        }
    }
    let settled: Vec<f64> = runs
        .iter()
        .filter(|&&(_, n)| n >= SETTLED)
        .map(|&(l, _)| l)
        .collect();
    let steps = settled.windows(2).filter(|w| w[0] != w[1]).count() as u64;
    // Two sides' tick grids that meet within the host's jitter make a frame
    // count for one tick or the next: two adjacent levels, in turn.
    let adjacent = settled.iter().copied().fold(f64::NAN, f64::max)
        - settled.iter().copied().fold(f64::NAN, f64::min)
        <= 1.0;
    assert!(
        steps <= 2 * underflows + missed || settled.is_empty() || adjacent,
        "the round trip changed level {steps} times, {underflows} underflows and {missed} \
         ticks missed counted; (level, GRTTs) {runs:?}"
    );
    // Only two adjacent levels in all: a flip, not an excursion.
    let levels = runs.iter().map(|r| r.0);
    let flip = levels.clone().fold(f64::NAN, f64::max) - levels.fold(f64::NAN, f64::min) <= 1.0;
    let in_excursion = runs
        .iter()
        .flat_map(|&(_, n)| std::iter::repeat_n(n < SETTLED && !flip, n));
    let (mut kept, mut strays) = (Vec::new(), Vec::new());
    for (&g, brief) in grtts.iter().zip(in_excursion) {
        let at_level = g - level(g) * period;
        if !brief && (at_level - median).abs() <= 2e-3 {
            kept.push(at_level);
        } else {
            strays.push(g);
        }
    }
    // A tenth, and two for each deadline a hub woke for 1 ms late: a
    // busy host puts a few GRTTs off now and then, a link that does not
    // regulate puts most of them off.
    let allowed = grtts.len() / 10 + 2 * missed as usize;
    assert!(
        strays.len() <= allowed,
        "{} GRTTs (less their release's lateness, at their level) in a brief excursion or \
         more than 2 ms from the median {median} s, {allowed} allowed ({missed} ticks \
         missed): {strays:?}; (level, GRTTs) {runs:?}",
        strays.len()
    );
    let n = kept.len() as f64;
    let mean = kept.iter().sum::<f64>() / n;
    let var = kept.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / n;
    (mean, var.sqrt())
}

/// Each GRTT less the lateness of the release that measured it: how far
/// past the base's release grid (the median phase of its releases, which
/// are on time but when the host holds the hub) it was released, up to
/// nine tenths of a period (a hub never releases early). What the host adds
/// is the hub's lateness, which its own
/// histogram reports; what is left is the link's.
fn on_schedule(grtts: &[(u64, f64)], period: u64) -> Vec<f64> {
    let period = period.max(1) as i64;
    let phase = |at: u64| (at % period as u64) as i64;
    let first = grtts.first().map_or(0, |&(at, _)| phase(at));
    // Phases from the first's, in [−T/2, T/2): the grid may sit near 0.
    let centred = |p: i64, from: i64| (p - from + period / 2).rem_euclid(period) - period / 2;
    let mut rel: Vec<i64> = grtts
        .iter()
        .map(|&(at, _)| centred(phase(at), first))
        .collect();
    rel.sort_unstable();
    let grid = first + rel[rel.len() / 2];
    // A hub never releases early: a phase past the grid is lateness, up to
    // nine tenths of a period (a tenth is left for the grid's own spread).
    let late = |p: i64| (p - grid + period / 10).rem_euclid(period) - period / 10;
    grtts
        .iter()
        .map(|&(at, g)| g - late(phase(at)).max(0) as f64 * 1e-9)
        .collect()
}

/// A tokio runtime for a test's connects and accepts (the links' hubs do
/// the rest).
pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap()
}
