//! `ndr sim --trace FILE.mcap` on recordings written here with the `mcap`
//! crate: the replay answers when the recorded remote answered, and puts
//! the recorded samples on its own, whatever the simulated set-up took.

mod cli_common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde_json::{Value, json};

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("ndr-cli-replay-{}-{name}", std::process::id()))
}

const PERIOD_NS: u64 = 50_000_000;
const ORIGIN: u64 = 1_700_000_000_000_000_000;

/// What a synthetic recording holds: both sides of a link at T = 50 ms,
/// attached at `ORIGIN`, its first command `lead_s` later, then `samples`
/// commands each way with a one-way delay of `delay_ms(k)` for the k-th,
/// and a remote that sends its state `answer_ticks` ticks after it
/// released the command it answers.
struct Synthetic {
    lead_s: f64,
    samples: u64,
    answer_ticks: u64,
    delay_ms: fn(u64) -> f64,
    /// The set-up's probes on `/ndr/probe` (none: the channel is left
    /// out, as in a recording made before it existed): how many each way,
    /// and the k-th one's delay in a direction (`fwd`, `bwd`), `None` for
    /// a probe that never arrived.
    probes: Option<(u64, ProbeDelay)>,
    /// Samples (by their number) never released, each way: lost.
    missing: fn(u64) -> bool,
    /// The clock offset estimate the first 8 probes each way were
    /// recorded with (the others' and the samples' is 0, as the clocks'):
    /// a young estimate.
    probe_offset_s: f64,
}

/// A probe's delay (ms) by its direction and number; `None`: never came.
type ProbeDelay = fn(&str, u64) -> Option<f64>;

/// Nothing missing.
fn none(_: u64) -> bool {
    false
}

impl Synthetic {
    fn write(&self, path: &Path) {
        let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
        let mut w = mcap::WriteOptions::new()
            .compression(None)
            .create(file)
            .unwrap();
        let schema = w
            .add_schema("ndr.Any", "jsonschema", br#"{"type":"object"}"#)
            .unwrap();
        let mut channels = BTreeMap::new();
        let mut topics = vec!["/ndr/event", "/ndr/command", "/ndr/state", "/ndr/network"];
        if self.probes.is_some() {
            topics.push("/ndr/probe");
        }
        for topic in topics {
            let id = w
                .add_channel(schema, topic, "json", &BTreeMap::new())
                .unwrap();
            channels.insert(topic, id);
        }
        let mut messages: Vec<(u64, &str, u64, Value)> = Vec::new();
        let event = |kind: &str, at: u64| json!({"link": 0, "side": "base", "kind": kind, "at_ns": at, "period_s": 0.05, "ns": 2});
        messages.push((ORIGIN, "/ndr/event", ORIGIN, event("attached", ORIGIN)));
        let first = ORIGIN + (self.lead_s * 1e9) as u64;
        messages.push((first, "/ndr/event", first, event("started", first)));
        // The probes go out a period apart from the attachment on, each
        // side numbering them from 0, and end before the first command.
        if let Some((count, delay_ms)) = self.probes {
            for k in 0..count {
                let sent = ORIGIN + k * PERIOD_NS;
                for direction in ["fwd", "bwd"] {
                    let Some(d) = delay_ms(direction, k) else {
                        continue;
                    };
                    let d = (d * 1e6) as u64;
                    let offset = if k < 8 { self.probe_offset_s } else { 0.0 };
                    messages.push((
                        sent + d,
                        "/ndr/probe",
                        sent,
                        json!({"link": 0, "direction": direction, "seq": k, "sent_ns": sent,
                               "arrived_ns": sent + d, "raw_s": d as f64 * 1e-9,
                               "one_way_s": d as f64 * 1e-9 - offset,
                               "clock_offset_s": offset}),
                    ));
                }
            }
        }
        // The remote releases each command a fixed 200 ms after its send.
        let hold = 200_000_000;
        for k in 0..self.samples {
            let d = ((self.delay_ms)(k) * 1e6) as u64;
            let status = if (self.missing)(k) { "late" } else { "fresh" };
            let sent = first + k * PERIOD_NS;
            let released = sent + hold;
            messages.push((
                released,
                "/ndr/command",
                sent,
                json!({"link": 1, "seq": k, "status": status, "sent_ns": sent,
                       "arrived_ns": sent + d, "released_ns": released,
                       "answers_sent_ns": null}),
            ));
            let state_sent = released + self.answer_ticks * PERIOD_NS;
            let state_released = state_sent + hold;
            messages.push((
                state_released,
                "/ndr/state",
                state_sent,
                json!({"link": 0, "seq": k, "status": status, "sent_ns": state_sent,
                       "arrived_ns": state_sent + d, "released_ns": state_released,
                       "answers_sent_ns": sent}),
            ));
            for (direction, at) in [("fwd", sent), ("bwd", state_sent)] {
                if (self.missing)(k) {
                    messages.push((
                        at + hold,
                        "/ndr/network",
                        at,
                        json!({"link": 0, "direction": direction, "seq": k, "sent_ns": at,
                               "arrived_ns": null, "raw_s": null, "one_way_s": null,
                               "clock_offset_s": 0.0, "missing": true}),
                    ));
                    continue;
                }
                messages.push((
                    at + d,
                    "/ndr/network",
                    at,
                    json!({"link": 0, "direction": direction, "seq": k, "sent_ns": at,
                           "arrived_ns": at + d, "raw_s": d as f64 * 1e-9,
                           "one_way_s": d as f64 * 1e-9, "clock_offset_s": 0.0,
                           "missing": false}),
                ));
            }
        }
        messages.sort_by_key(|m| m.0);
        for (sequence, (log_time, topic, publish_time, body)) in messages.into_iter().enumerate() {
            let header = mcap::records::MessageHeader {
                channel_id: channels[topic],
                sequence: sequence as u32,
                log_time,
                publish_time,
            };
            w.write_to_known_channel(&header, body.to_string().as_bytes())
                .unwrap();
        }
        w.finish().unwrap();
    }
}

fn replay(path: &Path, regulation: &str, underflow: &str) -> Value {
    replay_over(path, regulation, underflow, "tcp")
}

fn replay_over(path: &Path, regulation: &str, underflow: &str, transport: &str) -> Value {
    cli_common::json(&[
        "sim",
        "--trace",
        path.to_str().unwrap(),
        "--regulation",
        regulation,
        "--underflow",
        underflow,
        "--period-ms",
        "50",
        "--transport",
        transport,
        "--json",
    ])
}

#[test]
fn a_replay_answers_when_the_recorded_remote_did() {
    let rec = temp("answer.mcap");
    // 100 ms each way, released 200 ms after the send each way: a state
    // that answers at the next tick closes a round trip of 200 + 50 + 200
    // ms, one that answers in the tick of the release 400 ms.
    for (answer_ticks, grtt) in [(1, 0.450), (0, 0.400)] {
        Synthetic {
            lead_s: 1.0,
            samples: 400,
            answer_ticks,
            delay_ms: |_| 100.0,
            probes: None,
            missing: none,
            probe_offset_s: 0.0,
        }
        .write(&rec);
        let sim = replay(&rec, "constant:200", "hold");
        let g = sim["grtt_mean_s"].as_f64().unwrap();
        assert!(
            (g - grtt).abs() < 1e-6,
            "answering {answer_ticks} tick(s) later: GRTT {g} s, not {grtt} s"
        );
        assert!(sim["grtt_std_s"].as_f64().unwrap() < 1e-6);
        assert!(sim["grtt_count"].as_u64().unwrap() > 300);
    }
    let _ = std::fs::remove_file(&rec);
}

#[test]
fn a_replay_puts_the_recorded_samples_on_its_own() {
    let rec = temp("anchor.mcap");
    // A recorded set-up of 5 s (a congested handshake), then 20 s of
    // samples whose delay rises to 400 ms for the first 40 and then falls
    // back to 100 ms, a period at a time, as in-order delivery has it.
    Synthetic {
        lead_s: 5.0,
        samples: 400,
        answer_ticks: 1,
        delay_ms: |k| match k {
            0..40 => 400.0,
            40..46 => 400.0 - 50.0 * (k - 39) as f64,
            _ => 100.0,
        },
        probes: None,
        missing: none,
        probe_offset_s: 0.0,
    }
    .write(&rec);
    let sim = replay(&rec, "constant:300", "drop-late");
    // The replay ends with the recording's last sample, not 5 s later: as
    // many commands as the recording (the simulated set-up is shorter).
    let sent = sim["samples_sent"].as_u64().unwrap();
    assert!(
        (790..=802).contains(&sent),
        "{sent} samples sent each way together, not the recording's 800"
    );
    // Its first samples each way meet the recorded 400 ms, over the 300 ms
    // the regulation holds: the 40 of the episode and the first of its
    // fall are late, each way (a sample or two of the set-up's aside).
    let late = sim["late_samples"].as_u64().unwrap();
    assert!(
        (76..=84).contains(&late),
        "{late} late samples, not about 82"
    );
    let _ = std::fs::remove_file(&rec);
}

#[test]
fn a_replay_sizes_its_queue_from_the_recorded_probes() {
    let rec = temp("probes.mcap");
    // Forward probes 40 ms slower each than the one before, backward ones
    // at 100 ms: each echo closes a round trip 40 ms longer than the last,
    // so any ten of them span 360 ms, and the queue law sizes the queue at
    // 2 + floor(1.3 × 0.36 / 0.05) = 11. The samples' delays, a steady
    // 100 ms, would size it at 2.
    let recorded = |probes| Synthetic {
        lead_s: 2.0,
        samples: 200,
        answer_ticks: 1,
        delay_ms: |_| 100.0,
        probes,
        missing: none,
        probe_offset_s: 0.0,
    };
    let ramp: ProbeDelay = |direction, k| match direction {
        "fwd" => Some(100.0 + 40.0 * k as f64),
        _ => Some(100.0),
    };
    for (probes, ns) in [(Some((40, ramp)), 11), (None, 2)] {
        recorded(probes).write(&rec);
        for transport in ["tcp", "datagram"] {
            let sim = replay_over(&rec, "paper-static", "hold", transport);
            assert_eq!(
                sim["initial_ns"].as_u64(),
                Some(ns),
                "{transport}, probes recorded: {}",
                probes.is_some()
            );
        }
    }
    // The first probes never arrived (a datagram path not yet open): the
    // replay's are lost too, and its round trips come from the later ones.
    let late_start: ProbeDelay = |direction, k| match (direction, k) {
        (_, 0..5) => None,
        ("fwd", _) => Some(100.0 + 40.0 * k as f64),
        _ => Some(100.0),
    };
    recorded(Some((40, late_start))).write(&rec);
    let sim = replay_over(&rec, "paper-static", "hold", "datagram");
    assert_eq!(sim["initial_ns"].as_u64(), Some(11));
    // The first probes' delays recorded through a young clock offset
    // estimate, 358 ms off both ways (as a stalled handshake's stamps
    // leave it): the round trips they closed were what they were, and so
    // is the queue.
    Synthetic {
        probe_offset_s: -0.358,
        ..recorded(Some((40, ramp)))
    }
    .write(&rec);
    for transport in ["tcp", "datagram"] {
        let sim = replay_over(&rec, "paper-static", "hold", transport);
        assert_eq!(sim["initial_ns"].as_u64(), Some(11), "{transport}");
    }
    let _ = std::fs::remove_file(&rec);
}

#[test]
fn a_sample_never_released_is_lost_in_the_replay() {
    let rec = temp("lost.mcap");
    // Samples 100 to 129 each way were never released (an outage); the
    // others came in 100 ms, 200 ms before their release. Replayed as a
    // loss, the outage's datagrams never come: of the copies the first
    // datagram after it carries, those of samples 127 to 129 come before
    // their release (126's at its very release, 300 ms after its send:
    // missed), and samples 100 to 126 each way are missed at their
    // release, never late. Replayed as arriving with the sample after them
    // (a made-up delay), they would come, and be late.
    Synthetic {
        lead_s: 1.0,
        samples: 400,
        answer_ticks: 1,
        delay_ms: |_| 100.0,
        probes: None,
        missing: |k| (100..130).contains(&k),
        probe_offset_s: 0.0,
    }
    .write(&rec);
    let sim = replay_over(&rec, "constant:300", "drop-late", "datagram");
    assert_eq!(sim["late_samples"].as_u64(), Some(0), "{sim}");
    assert_eq!(sim["underflows"].as_u64(), Some(2 * 27), "{sim}");
    let _ = std::fs::remove_file(&rec);
}
