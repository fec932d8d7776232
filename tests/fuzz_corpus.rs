//! Replays the fuzzing corpus through the fuzz harnesses, so every input the
//! fuzzer kept (and every crash it ever found, once fixed) stays a test case.
//! The fuzzing itself runs with cargo-fuzz on nightly: see docs/reliability.md.

#[path = "../fuzz/harness.rs"]
mod harness;

use std::fs;
use std::path::Path;

fn replay(target: &str, run: fn(&[u8])) {
    let fuzz = Path::new(env!("CARGO_MANIFEST_DIR")).join("fuzz");
    replay_dir(&fuzz.join("corpus").join(target), run, true);
    // Inputs that once failed, kept by name whatever the corpus minimizer does.
    let regressions = fuzz.join("regressions").join(target);
    if regressions.exists() {
        replay_dir(&regressions, run, false);
    }
}

fn replay_dir(dir: &Path, run: fn(&[u8]), required: bool) {
    let mut files: Vec<_> = fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("a directory entry").path())
        .collect();
    files.sort();
    assert!(
        !required || !files.is_empty(),
        "{} holds no corpus",
        dir.display()
    );
    // Every file, on every core: the largest corpora would otherwise hold
    // the test command for a minute on one.
    let threads = std::thread::available_parallelism().map_or(1, usize::from);
    let failed: Vec<&Path> = std::thread::scope(|scope| {
        let lanes: Vec<_> = (0..threads)
            .map(|lane| {
                let files = &files;
                scope.spawn(move || {
                    files
                        .iter()
                        .skip(lane)
                        .step_by(threads)
                        .filter(|path| {
                            let data = fs::read(path).expect("a corpus file");
                            std::panic::catch_unwind(|| run(&data)).is_err()
                        })
                        .map(|path| path.as_path())
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        lanes
            .into_iter()
            .flat_map(|lane| lane.join().expect("a replay thread"))
            .collect()
    });
    // A failing input names itself: replay it with
    // `cargo +nightly fuzz run <target> <file>` for a backtrace.
    assert!(failed.is_empty(), "failed their harness: {failed:?}");
}

#[test]
fn the_frame_decoder_corpus_passes() {
    replay("frame_decoder", harness::decode);
}

#[test]
fn the_endpoint_corpus_passes() {
    replay("endpoint", harness::endpoint);
}

#[test]
fn the_pair_corpus_passes() {
    replay("pair", harness::pair);
}

#[test]
fn the_datagram_corpus_passes() {
    replay("datagram", harness::datagram);
}

#[test]
fn the_pair_script_runs_a_link_that_releases_both_ways() {
    // 1 axis, T = 10 ms, static, hold, FIFO, no watchdog; a stream (1) or
    // datagrams of 3 samples (6, then a session token); grids aligned;
    // then time only: 100 × 63.75 periods. On datagrams, every other op
    // first loses the base's next 2 datagrams: the copies recover them.
    for transport in [vec![1], vec![6, 7, 7, 7, 7, 7, 7]] {
        let datagram = transport.len() > 1;
        let mut script = vec![0, 9, 0, 0, 7 * 3];
        script.extend(&transport);
        script.push(0);
        for k in 0..100 {
            if datagram && k % 2 == 1 {
                script.extend([0, 4, 2]);
            }
            script.extend([0, 0, 255]);
        }
        let [base, remote] = harness::pair_stats(&script).expect("a valid configuration");
        assert!(base.released_fresh > 5000, "{base:?}");
        assert!(remote.released_fresh > 5000, "{remote:?}");
        assert_eq!((base.late, remote.late), (0, 0));
        if datagram {
            assert_eq!(remote.samples_recovered, 100, "{remote:?}");
            assert_eq!(remote.samples_lost, 0);
            assert!(base.datagrams_received > 5000 && remote.datagrams_received > 5000);
        } else {
            assert_eq!(base.datagrams_received + remote.datagrams_received, 0);
        }
    }
}

#[test]
fn the_datagram_script_takes_recovers_and_refuses_as_counted() {
    // 1 axis, T = 10 ms, static, hold, FIFO, no watchdog; 3 samples per
    // datagram, no repeats; two tokens; grids aligned; run to running.
    let mut script = vec![0, 9, 0, 0, 7 * 3, 2];
    script.extend(0x1111_2222_3333_4444_u64.to_le_bytes());
    script.extend(0x5555_6666_7777_8888_u64.to_le_bytes());
    script.extend([0, 1]);
    for k in 0..40 {
        match k % 4 {
            // The base's next 2 datagrams lost: the third's copies recover them.
            0 => script.extend([0, 4, 2]),
            // Its newest bundle again, once taken: stale.
            1 => script.extend([0, 5, 0]),
            // Forged with the token 0: foreign.
            2 => script.extend([0, 6, 0, 0, 7, 4]),
            // Ten bytes that are no frame, to the remote.
            _ => script.extend([1, 7, 10, 1].into_iter().chain([b'x'; 10])),
        }
        script.extend([0, 2, 255]);
    }
    let [base, remote] = harness::datagram_stats(&script).expect("a valid configuration");
    assert!(remote.released_fresh > 2000, "{remote:?}");
    assert_eq!(
        (remote.samples_recovered, remote.samples_lost),
        (20, 0),
        "{remote:?}"
    );
    assert_eq!(
        (
            remote.datagrams_stale,
            remote.datagrams_foreign,
            remote.datagrams_refused
        ),
        (10, 10, 10),
        "{remote:?}"
    );
    assert!(base.released_fresh > 2000, "{base:?}");
    assert_eq!(base.datagrams_stale + base.datagrams_foreign, 0, "{base:?}");
}
