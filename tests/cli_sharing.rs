//! A robot shared by several `ndr base` processes at once, as a user runs
//! them: a controller, an observer, a base waiting for control that is
//! handed it when the controller leaves or hangs, and (over QUIC, mutual
//! TLS) an observer's identity refused control. Margins are wide: what is
//! checked is who held control, in which order, and that no command of an
//! ended term was applied, not timing accuracy.

use std::path::{Path, PathBuf};
use std::process::ExitStatus;
use std::time::{Duration, Instant};

mod cli_proc;

use cli_proc::{Proc, serial};

type Value = serde_json::Value;

/// `ndr remote --observers 2 --once --json` on a free loopback port, with
/// `extra` arguments; its address.
fn remote(extra: &[&str]) -> (Proc, String) {
    let mut args = vec![
        "remote",
        "--listen",
        "127.0.0.1:0",
        "--period-ms",
        "20",
        "--observers",
        "2",
        "--once",
        "--json",
    ];
    args.extend_from_slice(extra);
    let mut remote = Proc::spawn(&args);
    let prefix = "waiting for bases on ";
    let line = remote.line_with(prefix, Duration::from_secs(20));
    let at = line.find(prefix).unwrap() + prefix.len();
    (
        remote,
        line[at..].split_whitespace().next().unwrap().to_string(),
    )
}

fn csv_path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("ndr-cli-sharing-{name}-{}.csv", std::process::id()))
}

/// `ndr base --json` to `addr` for `seconds`, with `extra` arguments.
fn base(addr: &str, seconds: &str, csv: &Path, extra: &[&str]) -> Proc {
    let mut args = vec![
        "base",
        "--connect",
        addr,
        "--duration-s",
        seconds,
        "--period-ms",
        "20",
        "--json",
        "--out",
    ];
    args.push(csv.to_str().unwrap());
    args.extend_from_slice(extra);
    Proc::spawn(&args)
}

/// Waits for `p` until `limit`: its exit status, its JSON report, and when
/// it was seen to exit.
fn report(p: Proc, limit: Duration) -> (ExitStatus, Value, Instant) {
    let (status, stdout, stderr) = p.wait(limit);
    let ended = Instant::now();
    let json = serde_json::from_str(&stdout)
        .unwrap_or_else(|e| panic!("no JSON report ({e}): {stdout:?}; stderr:\n{stderr}"));
    (status, json, ended)
}

/// The CSV's fresh states: (time, seq).
fn fresh_states(csv: &Path) -> Vec<(f64, u64)> {
    let text = std::fs::read_to_string(csv).expect("the CSV is written");
    text.lines()
        .skip(1)
        .filter_map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[2] == "fresh").then(|| (f[0].parse().unwrap(), f[1].parse().unwrap()))
        })
        .collect()
}

/// Throwaway identities for one test: the robot, the operators (who may
/// control), a watcher (pinned by its certificate) and an intruder (by its
/// fingerprint) who may only observe.
struct Identities {
    dir: PathBuf,
    robot: ndr::keygen::KeyPair,
    operator: ndr::keygen::KeyPair,
    watcher: ndr::keygen::KeyPair,
    intruder: ndr::keygen::KeyPair,
}

impl Identities {
    fn new(test: &str) -> Identities {
        let dir =
            std::env::temp_dir().join(format!("ndr-cli-sharing-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let pair = |name| ndr::keygen::write(&dir, name).expect("a certificate pair");
        Identities {
            robot: pair("robot"),
            operator: pair("operator"),
            watcher: pair("watcher"),
            intruder: pair("intruder"),
            dir,
        }
    }

    /// The remote's arguments: QUIC, controllers and observers apart.
    fn remote(&self) -> Vec<String> {
        let mut args = vec!["--transport".to_string(), "quic".into()];
        for (flag, path) in [
            ("--cert", &self.robot.cert),
            ("--key", &self.robot.key),
            ("--peer-cert", &self.operator.cert),
            ("--observer-cert", &self.watcher.cert),
        ] {
            args.push(flag.into());
            args.push(path.display().to_string());
        }
        args.push("--observer-pin".into());
        args.push(self.intruder.fingerprint.to_string());
        args
    }

    /// A base's arguments with `who`'s identity.
    fn base(&self, who: &ndr::keygen::KeyPair) -> Vec<String> {
        let mut args = vec!["--transport".to_string(), "quic".into()];
        for (flag, path) in [
            ("--cert", &who.cert),
            ("--key", &who.key),
            ("--peer-cert", &self.robot.cert),
        ] {
            args.push(flag.into());
            args.push(path.display().to_string());
        }
        args
    }
}

impl Drop for Identities {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn strs(args: &[String]) -> Vec<&str> {
    args.iter().map(String::as_str).collect()
}

/// A recording's fresh commands, by the number of their link.
fn fresh_commands(path: &Path) -> std::collections::BTreeMap<u64, u64> {
    let bytes = std::fs::read(path).expect("the recording exists");
    let mut by_link = std::collections::BTreeMap::new();
    for m in mcap::MessageStream::new(&bytes).expect("an MCAP file") {
        let m = m.expect("a whole recording");
        if m.channel.topic != "/ndr/command" {
            continue;
        }
        let body: Value = serde_json::from_slice(&m.data).expect("JSON");
        if body["status"] == "fresh" {
            *by_link.entry(body["link"].as_u64().unwrap()).or_default() += 1;
        }
    }
    by_link
}

fn session<'a>(remote: &'a Value, terms: &Value) -> &'a Value {
    remote["sessions"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| &s["terms"] == terms)
        .unwrap_or_else(|| panic!("no session with terms {terms}: {remote}"))
}

/// Over QUIC, mutual TLS: the operators' identity may control, the
/// watcher's and the intruder's only observe.
#[test]
fn a_waiting_base_is_handed_control_when_the_controller_leaves() {
    let _serial = serial();
    let ids = Identities::new("handover");
    let (mut remote, addr) = remote(&strs(&ids.remote()));
    let (csv_a, csv_o, csv_b) = (csv_path("a"), csv_path("o"), csv_path("b"));
    let csv_i = csv_path("i");
    // The intruder, an observer's identity, asks for control: refused,
    // and told why. (It comes first: once another base holds control, a
    // base asking for it is refused `busy` before its identity is weighed.)
    let i = base(&addr, "4", &csv_i, &strs(&ids.base(&ids.intruder)));
    let (status_i, report_i, _) = report(i, Duration::from_secs(60));
    let operator = ids.base(&ids.operator);
    let a = base(&addr, "6", &csv_a, &strs(&operator));
    let mut watcher = ids.base(&ids.watcher);
    watcher.push("--observe".into());
    let o = base(&addr, "14", &csv_o, &strs(&watcher));
    // B comes once A holds control (a loaded host may start A late).
    remote.line_with("holds control (term 1)", Duration::from_secs(20));
    std::thread::sleep(Duration::from_secs(1));
    let b_started = Instant::now();
    let mut waits = operator.clone();
    waits.extend(["--wait-for-control".into(), "20".into()]);
    let b = base(&addr, "4", &csv_b, &strs(&waits));

    let (status_a, report_a, a_ended) = report(a, Duration::from_secs(60));
    let (status_b, report_b, _) = report(b, Duration::from_secs(60));
    let (status_o, report_o, _) = report(o, Duration::from_secs(60));
    let (status_r, stdout_r, stderr_r) = remote.wait(Duration::from_secs(60));
    assert!(!status_i.success(), "{report_i}");
    assert_eq!(report_i["refused"], "observer_only", "{report_i}");
    let end_i = report_i["end"].as_str().unwrap();
    assert!(
        end_i.contains("observers' allow-list") && end_i.contains("--observe"),
        "{report_i}"
    );
    assert!(status_a.success(), "{report_a}");
    assert!(status_b.success(), "{report_b}");
    assert!(status_o.success(), "{report_o}");
    assert!(status_r.success(), "{stderr_r}");

    assert_eq!(report_a["role"], "controller", "{report_a}");
    assert_eq!(report_b["role"], "controller", "{report_b}");
    // (States of term 1 still on their way at the grant come first.)
    let terms_b = report_b["terms_seen"].as_array().unwrap();
    assert_eq!(terms_b.last(), Some(&serde_json::json!(2)), "{report_b}");
    // B was granted control when A left: its wait, from its start, ends
    // within 1.5 s of A's end.
    let waited = report_b["waited_for_control_s"].as_f64().expect("B waited");
    let granted = b_started + Duration::from_secs_f64(waited);
    let apart = if granted > a_ended {
        granted - a_ended
    } else {
        a_ended - granted
    };
    assert!(
        apart < Duration::from_millis(1500),
        "granted {apart:?} from A's end; {report_b}"
    );

    // The observer: its states in order, none missing for longer than the
    // hand-over holds the robot, both terms seen.
    assert_eq!(report_o["role"], "observer", "{report_o}");
    // (Term 0: it may have joined before A's grant.)
    let terms: Vec<u64> = report_o["terms_seen"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_u64)
        .filter(|&t| t != 0)
        .collect();
    assert_eq!(terms, [1, 2], "{report_o}");
    let states = fresh_states(&csv_o);
    assert!(states.len() > 300, "{} states", states.len());
    assert!(
        states.windows(2).all(|w| w[1].1 > w[0].1),
        "states out of order"
    );
    let gap = states
        .windows(2)
        .map(|w| w[1].0 - w[0].0)
        .fold(0.0, f64::max);
    assert!(gap < 1.5, "the observer went {gap} s without a state");

    // The robot: one hand-over; A's commands in term 1, B's in term 2;
    // none of an ended term applied.
    let r: Value = serde_json::from_str(&stdout_r)
        .unwrap_or_else(|e| panic!("no JSON report ({e}): {stdout_r:?}; stderr:\n{stderr_r}"));
    assert_eq!(r["handovers"], 1, "{r}");
    assert_eq!(r["refused_observer_only"], 1, "{r}");
    assert!(r["observers_max"].as_u64() >= Some(2), "{r}");
    assert_eq!(r["commands_after_term"], 0, "{r}");
    let sa = session(&r, &serde_json::json!([1]));
    let sb = session(&r, &serde_json::json!([2]));
    assert!(sa["commands_applied"].as_u64() > Some(100), "{r}");
    assert!(sb["commands_applied"].as_u64() > Some(50), "{r}");
    assert_eq!(sa["commands_after_term"], 0, "{r}");
    let by_term = &r["commands_applied_by_term"];
    assert_eq!(by_term[0][1], sa["commands_applied"], "{r}");
    assert_eq!(by_term[1][1], sb["commands_applied"], "{r}");
    let so = session(&r, &serde_json::json!([]));
    assert_eq!(so["role"], "observer", "{r}");
    assert_eq!(so["commands_applied"], 0, "{r}");
    for csv in [csv_a, csv_o, csv_b, csv_i] {
        let _ = std::fs::remove_file(csv);
    }
}

/// The remote drops a base silent for the liveness time (10 s).
const LIVENESS_S: f64 = 10.0;

#[cfg(unix)]
#[test]
fn a_hung_controller_is_replaced_by_the_waiting_base_within_the_liveness_time() {
    let _serial = serial();
    // The shared remote records its side of every link.
    let rec = csv_path("hung").with_extension("mcap");
    let (mut remote, addr) = remote(&["--record", rec.to_str().unwrap()]);
    let (csv_a, csv_b) = (csv_path("hung-a"), csv_path("hung-b"));
    let a = base(&addr, "60", &csv_a, &[]);
    remote.line_with("holds control (term 1)", Duration::from_secs(20));
    let b_started = Instant::now();
    let b = base(&addr, "2", &csv_b, &["--wait-for-control", "30"]);
    std::thread::sleep(Duration::from_secs(2));
    a.signal("STOP");
    let stopped = Instant::now();

    let (status_b, report_b, _) = report(b, Duration::from_secs(60));
    a.signal("CONT");
    // A finds its link gone, and says so.
    let (status_a, _, _) = a.wait(Duration::from_secs(60));
    let (_, stdout_r, stderr_r) = remote.wait(Duration::from_secs(60));
    assert!(
        status_b.success(),
        "{report_b}\nthe remote: {stdout_r}\n{stderr_r}"
    );
    assert!(!status_a.success());
    assert_eq!(report_b["role"], "controller", "{report_b}");
    let waited = report_b["waited_for_control_s"].as_f64().expect("B waited");
    let granted = b_started + Duration::from_secs_f64(waited);
    // Not before A went silent for most of the liveness time, and not
    // much after it.
    let after = granted.saturating_duration_since(stopped).as_secs_f64();
    assert!(
        after > LIVENESS_S - 3.0 && after < LIVENESS_S + 3.0,
        "granted {after} s after A stopped; {report_b}"
    );
    let r: Value = serde_json::from_str(&stdout_r)
        .unwrap_or_else(|e| panic!("no JSON report ({e}): {stdout_r:?}; stderr:\n{stderr_r}"));
    assert_eq!(r["handovers"], 1, "{r}");
    assert_eq!(r["commands_after_term"], 0, "{r}");
    let sa = session(&r, &serde_json::json!([1]));
    assert!(sa["end"].as_str().unwrap().contains("silent"), "{r}");
    // Each base's commands, on its own link's number: A's, then B's.
    let fresh = fresh_commands(&rec);
    assert_eq!(
        fresh.keys().copied().collect::<Vec<_>>(),
        [0, 1],
        "{fresh:?}"
    );
    assert!(fresh.values().all(|&n| n > 50), "{fresh:?}");
    assert!(stderr_r.contains("ndr remote: recorded"), "{stderr_r}");
    for f in [csv_a, csv_b, rec] {
        let _ = std::fs::remove_file(f);
    }
}

/// `ndr demo --observers 2`: the operator's run, and two observers through
/// the relay that saw the robot's state and the commands it applied, in
/// the operator's term.
#[test]
fn the_demo_runs_with_observers_watching() {
    let _serial = serial();
    let csv = csv_path("demo");
    let p = Proc::spawn(&[
        "demo",
        "--observers",
        "2",
        "--transport",
        "tcp",
        "--duration-s",
        "4",
        "--json",
        "--out",
        csv.to_str().unwrap(),
    ]);
    let (status, r, _) = report(p, Duration::from_secs(60));
    assert!(status.success(), "{r}");
    let observers = r["observers"].as_array().expect("the observers' reports");
    assert_eq!(observers.len(), 2, "{r}");
    for o in observers {
        assert_eq!(o["ok"], true, "{r}");
        assert!(o["states_fresh"].as_u64() > Some(10), "{r}");
        assert!(o["applied_seen"].as_u64() > Some(10), "{r}");
        assert!(
            o["terms_seen"].as_array().unwrap().contains(&1.into()),
            "{r}"
        );
    }
    let _ = std::fs::remove_file(csv);
}

/// A raw frame of the wire (docs/wire.md, sections 2 and 7): no echo,
/// nothing released, term 0.
fn raw_frame(kind: u8, payload: &[u8], seq: u64, sent_at: u64) -> Vec<u8> {
    let mut f = Vec::with_capacity(48 + payload.len());
    f.extend_from_slice(&u32::try_from(48 + payload.len()).unwrap().to_le_bytes());
    f.extend_from_slice(&[4, kind, 0, 0]);
    for field in [seq, sent_at, u64::MAX, 0, u64::MAX] {
        f.extend_from_slice(&field.to_le_bytes());
    }
    f.extend_from_slice(payload);
    f
}

/// An observer on a raw socket that floods its session: its Hello (seat
/// observe), a probe a period, RESUME after ten, and between them Control
/// `yield` frames (an observer's is a no-op to the remote) as fast as the
/// socket takes them, until `until`. The frames it sent.
fn flood(addr: &str, period_ns: u64, until: Instant) -> u64 {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(addr).expect("the flooder connects");
    s.set_nodelay(true).unwrap();
    let mut hello = vec![0, 0, 0, 1];
    hello.extend_from_slice(&1_u16.to_le_bytes());
    hello.extend_from_slice(&1_u16.to_le_bytes());
    hello.extend_from_slice(&period_ns.to_le_bytes());
    hello.extend_from_slice(&[0; 16]);
    s.write_all(&raw_frame(2, &hello, 0, 0)).unwrap();
    let mut reader = s.try_clone().unwrap();
    std::thread::spawn(move || {
        let mut buf = [0; 65536];
        while reader.read(&mut buf).is_ok_and(|n| n > 0) {}
    });
    let control = |op: u8, ns: u16, period: u64, seq: u64, at: u64| {
        let mut p = vec![op, 0];
        p.extend_from_slice(&ns.to_le_bytes());
        p.extend_from_slice(&[0; 4]);
        p.extend_from_slice(&period.to_le_bytes());
        raw_frame(3, &p, seq, at)
    };
    let origin = Instant::now();
    let (mut tick, mut sent) = (None::<u64>, 0_u64);
    while Instant::now() < until {
        let now = u64::try_from(origin.elapsed().as_nanos()).unwrap();
        let k = now / period_ns;
        if tick.is_none_or(|t| k > t) {
            tick = Some(k);
            let mut out = raw_frame(1, &[], k, k * period_ns);
            if k == 10 {
                out.extend(control(3, 2, period_ns, k + 1, now));
            }
            if s.write_all(&out).is_err() {
                break;
            }
            continue;
        }
        let burst = control(6, 0, 0, k + 1, now).repeat(64);
        if s.write_all(&burst).is_err() {
            break;
        }
        sent += 64;
    }
    // (The reader's clone of the socket would hold it open.)
    let _ = s.shutdown(std::net::Shutdown::Both);
    sent
}

/// An observer that floods the remote with frames costs the controller
/// nothing: the remote reads a link no further than a few frames a tick,
/// whatever its peer sends.
#[test]
fn an_observer_flooding_the_remote_leaves_the_controller_alone() {
    let _serial = serial();
    let (mut remote, addr) = remote(&[]);
    let csv = csv_path("flooded");
    let a = base(&addr, "5", &csv, &[]);
    remote.line_with("holds control (term 1)", Duration::from_secs(20));
    let flooded = flood(&addr, 20_000_000, Instant::now() + Duration::from_secs(4));
    let (status_a, report_a, _) = report(a, Duration::from_secs(60));
    let (_, stdout_r, _) = remote.wait(Duration::from_secs(60));
    assert!(status_a.success(), "{report_a}");
    // The remote reads a link a few frames a tick: TCP's flow control
    // holds the flood back (unbounded, the remote took millions of
    // frames in the 4 s).
    assert!(
        flooded > 1000 && flooded < 1_000_000,
        "the remote took {flooded} frames"
    );
    // The controller: its round trip as steady as unflooded (flooded
    // unbounded, it swung by a few periods), no tick without its sample.
    let released = report_a["samples_released"].as_u64().unwrap();
    let missed =
        report_a["underflows"].as_u64().unwrap() + report_a["late_samples"].as_u64().unwrap();
    assert!(released > 100, "{report_a}");
    assert!(missed * 20 < released, "{missed} of {released}: {report_a}");
    let std = report_a["grtt_std_s"].as_f64().unwrap();
    assert!(std < 0.020, "GRTT std {std} s: {report_a}");
    let r: Value = serde_json::from_str(&stdout_r).unwrap();
    assert_eq!(r["handovers"], 0, "{r}");
    let _ = std::fs::remove_file(csv);
}
