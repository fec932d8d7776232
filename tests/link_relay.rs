//! The real link through the delay relay, on loopback: regulated delivery,
//! agreement with the simulator, and a relay killed mid-run.

use std::net::SocketAddr;
use std::time::Duration as StdDuration;

use ndr::core::endpoint::{Config, LinkError, Status};
use ndr::core::time::Duration;
use ndr::core::wire::Role;
use ndr::net::{Link, LinkConfig, Listener, NetError, Relay, RelayHandle};
use ndr::sim::delay::DelayModel;
use ndr::sim::{SimConfig, run};

// The shared run and its judgement, not the loopback tests' own helpers.
#[allow(dead_code)]
mod common;

const T: Duration = Duration::from_millis(10);

fn config() -> LinkConfig {
    let mut c = Config::paper(Role::Base);
    c = c.with_width(1);
    c.period = T;
    LinkConfig::new(c)
}

struct Setup {
    rt: tokio::runtime::Runtime,
    base: Link,
    remote: Link,
    relay: RelayHandle,
}

fn setup(model: DelayModel) -> Setup {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    let any: SocketAddr = "127.0.0.1:0".parse().unwrap();
    let (base, remote, relay) = rt.block_on(async {
        let listener = Listener::listen(any, config()).await.unwrap();
        let relay = Relay::listen(any, listener.local_addr().unwrap(), model, 7)
            .await
            .unwrap()
            .spawn()
            .unwrap();
        let (r, b) = tokio::join!(
            listener.accept(),
            Link::connect(relay.local_addr(), config())
        );
        (b.unwrap(), r.unwrap(), relay)
    });
    Setup {
        rt,
        base,
        remote,
        relay,
    }
}

/// The remote echoes each released command until its link ends; returns the
/// fresh sequence numbers and how it ended.
fn echo(mut remote: Link) -> std::thread::JoinHandle<(Vec<u64>, NetError)> {
    std::thread::spawn(move || {
        let mut seqs = Vec::new();
        loop {
            match remote.recv_timeout(StdDuration::from_secs(3)) {
                Ok(s) => {
                    if s.status == Status::Fresh {
                        seqs.push(s.seq);
                    }
                    let _ = remote.send(s.values());
                }
                Err(e) => return (seqs, e),
            }
        }
    })
}

#[test]
fn through_the_relay_every_sample_arrives_once_in_order_and_grtt_matches_the_simulator() {
    // The simulator on the same profile and period, over seeds: the
    // initialization pattern's 10 draws decide ns (2 or 3 here), and the real
    // peers' tick grids have an arbitrary phase where the simulator's share
    // one, which moves each direction's wait for a tick by under a period:
    // GRTT by under two.
    let sims: Vec<_> = (1..=10)
        .map(|seed| {
            let mut cfg = SimConfig::paper(DelayModel::Lan75km);
            cfg.period = T;
            cfg.seed = seed;
            cfg.duration = ndr::core::time::Duration::from_secs(10);
            run(&cfg).unwrap().report
        })
        .collect();
    let lo = sims
        .iter()
        .map(|r| r.grtt_mean_s)
        .fold(f64::INFINITY, f64::min);
    let hi = sims.iter().map(|r| r.grtt_mean_s).fold(0.0, f64::max);
    let t = T.as_secs_f64();
    // A shared host sometimes holds a peer or the relay. During the
    // initialization pattern that lengthens its round trips, and the link
    // sizes its queues for what it measured: an ns the relay's delays alone
    // never give, and the GRTT of that ns (correct, but not the
    // simulator's). While running, a hub held past the queue's slack makes
    // the paper's FIFO (under hold) step its delay up a period, by design.
    // The comparison is judged on a run whose pattern measured the network
    // and whose hubs were served on time, five runs at most; the last is
    // judged whatever it saw.
    const ATTEMPTS: u32 = 5;
    for attempt in 1..=ATTEMPTS {
        let Setup {
            rt,
            base,
            remote,
            relay,
        } = setup(DelayModel::Lan75km);
        let run = common::echo_run(base, remote);
        let _ = rt.block_on(relay.shutdown());
        common::assert_every_sample_once_in_order(&run);
        // A hub served late (the network's delays make NRTT and one-way
        // delays no sign of the host here).
        let stalls = std::iter::once(&run.base)
            .chain(&run.remote)
            .flat_map(|s| [s.lateness.max, s.release_lateness.max])
            .filter(|&late| late >= Duration::from_millis(1))
            .count() as u64;
        let (ns, grtt) = (run.base.ns, run.base.endpoint.grtt);
        let simulated = sims.iter().any(|r| r.ns == ns);
        if attempt < ATTEMPTS && (stalls > 0 || !simulated) {
            eprintln!(
                "run {attempt}: the host held a hub ({stalls} signs: latest deadline {}) or \
                 the pattern (ns {ns}, GRTT {} s ± {} s); judged on another",
                run.base.lateness.max,
                grtt.mean(),
                grtt.std()
            );
            continue;
        }
        // Constant, judged as every regulated link is (at its level, on the
        // schedule, if the host held this last run too).
        let (_, std) = common::grtt_judged(&run, stalls);
        assert!(std <= 1e-3, "GRTT std {std} s ({stalls} stalls): {grtt:?}");
        assert!(simulated, "ns {ns} never simulated");
        assert!(
            grtt.mean() >= lo - 2.0 * t - 0.002 && grtt.mean() <= hi + 2.0 * t + 0.002,
            "GRTT real {} s (ns {ns}) vs simulated {lo}..{hi} s",
            grtt.mean(),
        );
        break;
    }
}

#[test]
fn a_relay_killed_mid_run_is_reported_by_both_ends_within_a_second() {
    let Setup {
        rt,
        mut base,
        remote,
        relay,
    } = setup(DelayModel::Constant {
        fwd: Duration::from_millis(5),
        bwd: Duration::from_millis(5),
    });
    let robot = echo(remote);
    for k in 0..50 {
        base.send(&[f64::from(k)]).unwrap();
        base.recv_timeout(StdDuration::from_secs(3)).unwrap();
    }
    let killed = std::time::Instant::now();
    let _ = rt.block_on(relay.shutdown());
    let err = loop {
        match base.recv_timeout(StdDuration::from_secs(3)) {
            Ok(_) => continue,
            Err(e) => break e,
        }
    };
    assert!(
        killed.elapsed() < StdDuration::from_secs(1),
        "base: {:?}",
        killed.elapsed()
    );
    assert!(
        matches!(err, NetError::Link(LinkError::Disconnected)),
        "{err:?}"
    );
    let (_, remote_err) = robot.join().unwrap();
    assert!(
        killed.elapsed() < StdDuration::from_secs(1),
        "remote: {:?}",
        killed.elapsed()
    );
    assert!(
        matches!(remote_err, NetError::Link(LinkError::Disconnected)),
        "{remote_err:?}"
    );
}
