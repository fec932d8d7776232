//! `--record FILE.mcap`: the recording read back with the `mcap` crate (not
//! ndr's own reader) agrees with the run's report, and a process killed
//! without warning leaves a file readable up to its last second.

mod cli_common;

use std::collections::{BTreeMap, HashSet};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use mcap::read::{MessageStream, Options};
use serde_json::Value;

/// The tests run one at a time: each runs real-time links.
static SERIAL: Mutex<()> = Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    SERIAL
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("ndr-cli-record-{}-{name}", std::process::id()))
}

struct Msg {
    topic: String,
    log_time: u64,
    body: Value,
}

/// The messages of the file up to its first damaged record (all of them
/// for a whole file), and whether it was whole.
fn read(path: &Path) -> (Vec<Msg>, bool) {
    let bytes = std::fs::read(path).expect("the recording exists");
    let stream = MessageStream::new_with_options(&bytes, Options::IgnoreEndMagic.into())
        .expect("the file starts as an MCAP file");
    let mut out = Vec::new();
    for m in stream {
        let Ok(m) = m else {
            return (out, false);
        };
        out.push(Msg {
            topic: m.channel.topic.clone(),
            log_time: m.log_time,
            body: serde_json::from_slice(&m.data).expect("each message is JSON"),
        });
    }
    (out, true)
}

fn on<'a>(msgs: &'a [Msg], topic: &str) -> Vec<&'a Msg> {
    msgs.iter().filter(|m| m.topic == topic).collect()
}

fn fresh(msgs: &[&Msg]) -> usize {
    msgs.iter().filter(|m| m.body["status"] == "fresh").count()
}

/// How long the recorded demo runs (s), of which the checks leave
/// `START_S` to its start and end: a stats message a second from each
/// side over the rest, and 20 fresh states a second at its 50 ms period.
const DEMO_S: u64 = 10;
const START_S: u64 = 5;

/// One demo, recorded, is checked for what its recording holds and then
/// replayed in the simulator: a real run is the test's slow part.
#[test]
fn a_recorded_demo_agrees_with_its_report_and_replays_in_the_simulator() {
    let _serial = serial();
    let (rec, csv) = (temp("demo.mcap"), temp("demo.csv"));
    let report = cli_common::json(&[
        "demo",
        "--duration-s",
        &DEMO_S.to_string(),
        "--record",
        rec.to_str().unwrap(),
        "--out",
        csv.to_str().unwrap(),
        "--json",
    ]);
    let bytes = std::fs::read(&rec).unwrap();
    let summary = mcap::Summary::read(&bytes)
        .expect("the summary reads")
        .expect("a finished recording has a summary");
    let mut topics: Vec<(String, String, String)> = summary
        .channels
        .values()
        .map(|c| {
            let s = c.schema.as_ref().expect("every channel has a schema");
            assert!(!s.data.is_empty(), "{} has an empty schema", c.topic);
            (c.topic.clone(), s.name.clone(), s.encoding.clone())
        })
        .collect();
    topics.sort();
    let names: Vec<&str> = topics.iter().map(|t| t.0.as_str()).collect();
    assert_eq!(
        names,
        [
            "/ndr/command",
            "/ndr/event",
            "/ndr/network",
            "/ndr/probe",
            "/ndr/state",
            "/ndr/stats"
        ]
    );
    assert!(topics.iter().all(|t| t.2 == "jsonschema"), "{topics:?}");
    assert!(
        !summary.chunk_indexes.is_empty(),
        "the file is chunked and indexed"
    );

    let (msgs, whole) = read(&rec);
    assert!(whole);
    let (states, commands) = (on(&msgs, "/ndr/state"), on(&msgs, "/ndr/command"));
    let released = report["samples_released"].as_u64().unwrap();
    assert_eq!(
        (fresh(&states) + fresh(&commands)) as u64,
        released,
        "the demo's samples_released counts both sides' fresh releases"
    );
    // Every fresh row of the CSV is a fresh state of the recording (which
    // also has the releases after the operator stopped reading).
    let recorded: HashSet<u64> = states
        .iter()
        .filter(|m| m.body["status"] == "fresh")
        .map(|m| m.body["seq"].as_u64().unwrap())
        .collect();
    let csv_fresh: Vec<u64> = std::fs::read_to_string(&csv)
        .unwrap()
        .lines()
        .filter(|l| l.contains(",fresh,"))
        .map(|l| l.split(',').nth(1).unwrap().parse().unwrap())
        .collect();
    assert!(csv_fresh.len() > 100, "{} fresh states", csv_fresh.len());
    assert!(csv_fresh.iter().all(|seq| recorded.contains(seq)));
    for topic in [&states, &commands] {
        assert!(
            topic.windows(2).all(|w| w[0].log_time <= w[1].log_time),
            "log times go back"
        );
    }

    // GRTT from the times alone: a state's release minus the send of the
    // command it answers, found on /ndr/command by its send time.
    let sent: HashSet<u64> = commands
        .iter()
        .map(|m| m.body["sent_ns"].as_u64().unwrap())
        .collect();
    let mut grtts = Vec::new();
    for m in &states {
        if let Some(answers) = m.body["answers_sent_ns"].as_u64() {
            assert!(
                sent.contains(&answers),
                "the answered command is on /ndr/command"
            );
            grtts.push((m.body["released_ns"].as_u64().unwrap() - answers) as f64 * 1e-9);
        }
    }
    let mean = grtts.iter().sum::<f64>() / grtts.len() as f64;
    let reported = report["grtt_mean_s"].as_f64().unwrap();
    assert_eq!(grtts.len() as u64, report["grtt_count"].as_u64().unwrap());
    assert!(
        (mean - reported).abs() < 1e-6,
        "GRTT from the recording {mean} s, reported {reported} s"
    );
    assert_eq!(report["recording"]["dropped"], 0, "{}", report["recording"]);
    // A stats message a second from each side, events, and an arrival per
    // fresh release.
    assert!(on(&msgs, "/ndr/stats").len() as u64 >= 2 * (DEMO_S - START_S));
    let kinds: BTreeMap<String, usize> =
        on(&msgs, "/ndr/event")
            .iter()
            .fold(BTreeMap::new(), |mut k, m| {
                *k.entry(m.body["kind"].as_str().unwrap().to_owned())
                    .or_default() += 1;
                k
            });
    assert_eq!(kinds.get("attached"), Some(&2), "{kinds:?}");
    let arrivals = on(&msgs, "/ndr/network");
    assert_eq!(
        arrivals
            .iter()
            .filter(|m| m.body["missing"] == false)
            .count() as u64,
        released
    );

    // The set-up's probes, each way, numbered as sent: before the first
    // sample that way (probes and samples share the count).
    for (direction, topic) in [("fwd", "/ndr/command"), ("bwd", "/ndr/state")] {
        let seqs: Vec<u64> = on(&msgs, "/ndr/probe")
            .iter()
            .filter(|m| m.body["direction"] == direction)
            .map(|m| m.body["seq"].as_u64().unwrap())
            .collect();
        assert!(!seqs.is_empty(), "no {direction} probe recorded");
        assert!(
            seqs.windows(2).all(|w| w[0] < w[1]),
            "{direction}: {seqs:?}"
        );
        let first_sample = on(&msgs, topic)
            .iter()
            .map(|m| m.body["seq"].as_u64().unwrap())
            .min()
            .unwrap();
        assert!(
            seqs.iter().all(|&s| s < first_sample),
            "{direction}: {seqs:?}"
        );
    }

    let sim = cli_common::json(&[
        "sim",
        "--trace",
        rec.to_str().unwrap(),
        "--regulation",
        "adaptive",
        "--period-ms",
        "50",
        "--transport",
        "datagram",
        "--json",
    ]);
    // The replay runs for about the recording's length (its accuracy is
    // judged on a recording made for it, below, not on a real run).
    let d = sim["duration_s"].as_f64().unwrap();
    let recorded = DEMO_S as f64;
    assert!(
        (recorded - 2.0..recorded + 4.0).contains(&d),
        "replayed for {d} s"
    );
    assert!(sim["samples_released"].as_u64().unwrap() > 0);
    let _ = std::fs::remove_file(&rec);
    let _ = std::fs::remove_file(&csv);
}

fn unix_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_nanos() as u64
}

#[test]
fn a_recording_base_killed_mid_run_leaves_all_but_its_last_second() {
    let _serial = serial();
    let (rec, csv) = (temp("killed.mcap"), temp("killed.csv"));
    let mut remote = Command::new(env!("CARGO_BIN_EXE_ndr"))
        .args(["remote", "--listen", "127.0.0.1:0", "--once"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("ndr remote starts");
    let mut lines = BufReader::new(remote.stderr.take().unwrap()).lines();
    let addr = loop {
        let line = lines
            .next()
            .expect("the remote says where it listens")
            .unwrap();
        if let Some(at) = line.split("waiting for a base on ").nth(1) {
            break at.split_whitespace().next().unwrap().to_owned();
        }
    };
    // The remote's stderr keeps draining, so that it never blocks on it.
    std::thread::spawn(move || lines.for_each(drop));
    let mut base = Command::new(env!("CARGO_BIN_EXE_ndr"))
        .args(["base", "--connect", &addr, "--duration-s", "60", "--json"])
        .args(["--record", rec.to_str().unwrap()])
        .args(["--out", csv.to_str().unwrap()])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("ndr base starts");
    // Killed once its states have flowed a while.
    let start = Instant::now();
    let rows = || {
        std::fs::read_to_string(&csv)
            .map(|t| t.lines().count())
            .unwrap_or(0)
    };
    while rows() < 60 && start.elapsed() < Duration::from_secs(30) {
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(1500));
    base.kill().expect("SIGKILL");
    let killed_at = unix_ns();
    let _ = base.wait();
    let _ = remote.kill();
    let _ = remote.wait();

    let (msgs, whole) = read(&rec);
    // Whole or cut inside a record: either way the rest reads.
    let _ = whole;
    let states = on(&msgs, "/ndr/state");
    assert!(
        states.len() >= 40,
        "{} states read from the killed recording",
        states.len()
    );
    let last = msgs.iter().map(|m| m.log_time).max().unwrap();
    // A chunk a second, and half a second for the host's scheduling of the
    // writer thread.
    let lost_s = killed_at.saturating_sub(last) as f64 * 1e-9;
    assert!(
        lost_s < 1.5,
        "the readable part ends {lost_s:.3} s before the kill"
    );
    let _ = std::fs::remove_file(&rec);
    let _ = std::fs::remove_file(&csv);
}

/// An MCAP file with the channels of a recording and, on `/ndr/network`,
/// a sample every 50 ms each way for `seconds`, forward delays `fwd_ms`
/// and backward `bwd_ms`.
fn synthetic(path: &Path, seconds: u64, fwd_ms: f64, bwd_ms: f64) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = mcap::WriteOptions::new()
        .compression(None)
        .create(file)
        .unwrap();
    let schema = w
        .add_schema("ndr.Arrival", "jsonschema", br#"{"type":"object"}"#)
        .unwrap();
    let network = w
        .add_channel(schema, "/ndr/network", "json", &BTreeMap::new())
        .unwrap();
    let origin = 1_700_000_000_000_000_000u64;
    let mut seq = 0;
    for k in 0..seconds * 20 {
        for (direction, ms) in [("fwd", fwd_ms), ("bwd", bwd_ms)] {
            let sent = origin + k * 50_000_000;
            let body = serde_json::json!({
                "link": 0, "direction": direction, "seq": k, "sent_ns": sent,
                "arrived_ns": sent + (ms * 1e6) as u64, "raw_s": ms * 1e-3,
                "one_way_s": ms * 1e-3, "clock_offset_s": 0.0, "missing": false,
            });
            let header = mcap::records::MessageHeader {
                channel_id: network,
                sequence: seq,
                log_time: sent + (ms * 1e6) as u64,
                publish_time: sent,
            };
            seq += 1;
            w.write_to_known_channel(&header, body.to_string().as_bytes())
                .unwrap();
        }
    }
    w.finish().unwrap();
}

#[test]
fn a_recordings_measured_delays_are_the_simulated_networks() {
    let rec = temp("synthetic.mcap");
    synthetic(&rec, 30, 30.0, 70.0);
    let sim = cli_common::json(&[
        "sim",
        "--trace",
        rec.to_str().unwrap(),
        "--period-ms",
        "50",
        "--json",
    ]);
    assert_eq!(sim["profile"], "trace");
    // As long as the recording, and its delays: a round trip of their sum
    // (how it splits between the directions no clock estimate can tell;
    // the trace's own tests check each direction).
    let d = sim["duration_s"].as_f64().unwrap();
    assert!((29.0..31.0).contains(&d), "replayed for {d} s");
    let nrtt = sim["nrtt_mean_s"].as_f64().unwrap();
    assert!((nrtt - 0.100).abs() < 1e-6, "NRTT {nrtt} s");
    assert!(sim["nrtt_std_s"].as_f64().unwrap() < 1e-6);
    // A recording without arrivals, and a file that is neither a recording
    // nor a trace, are refused, each saying why.
    synthetic(&rec, 0, 0.0, 0.0);
    let out = cli_common::ndr(&["sim", "--trace", rec.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no arrival on /ndr/network"));
    std::fs::write(&rec, "t_s,seq\n").unwrap();
    let out = cli_common::ndr(&["sim", "--trace", rec.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("header"));
    let _ = std::fs::remove_file(&rec);
}
