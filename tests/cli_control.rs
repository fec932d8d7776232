//! `ndr control` as a user runs it: one JSON object with a row per link,
//! the Smith loop exact over the static FIFO, the bilateral energy account,
//! refusals that say what to do.

mod cli_common;
use cli_common::{json, ndr};

#[test]
fn tracking_has_a_row_per_link_and_the_static_fifo_is_exact() {
    let v = json(&[
        "control",
        "--scenario",
        "tracking",
        "--profile",
        "lan-75km",
        "--seeds",
        "1",
        "--duration-s",
        "30",
        "--json",
    ]);
    assert_eq!(v["schema"], "ndr-control/1");
    let rows = v["rows"].as_array().unwrap();
    let links: Vec<&str> = rows.iter().map(|r| r["link"].as_str().unwrap()).collect();
    assert_eq!(
        links,
        [
            "ideal",
            "unregulated",
            "paper-static",
            "paper-dynamic",
            "adaptive"
        ]
    );
    for r in rows {
        for key in [
            "rms_vs_reference",
            "rms_vs_delayed_design",
            "overshoot",
            "settling_s",
            "stable",
        ] {
            assert!(r["mean"].get(key).is_some(), "{key} missing in {r}");
        }
    }
    let row = |name: &str| rows.iter().find(|r| r["link"] == name).unwrap();
    assert_eq!(
        row("ideal")["max_rms_vs_delayed_design"].as_f64(),
        Some(0.0)
    );
    assert!(
        row("paper-static")["max_rms_vs_delayed_design"]
            .as_f64()
            .unwrap()
            <= 1e-9
    );
    assert!(
        row("paper-static")["mean"]["round_trip_mean_ticks"]
            .as_f64()
            .unwrap()
            > 2.0
    );
}

#[test]
fn bilateral_rows_carry_the_energy_account_and_links_can_be_chosen() {
    let v = json(&[
        "control",
        "--scenario",
        "bilateral",
        "--link",
        "ideal",
        "--link",
        "paper-static",
        "--family",
        "step",
        "--seeds",
        "1",
        "--duration-s",
        "30",
        "--json",
    ]);
    let rows = v["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    for r in rows {
        for key in [
            "energy_generated",
            "energy_through",
            "contact_force_rms_error",
            "position_rms_error",
        ] {
            assert!(r["mean"][key].as_f64().is_some(), "{key} missing in {r}");
        }
        assert!(
            r["mean"]["energy_generated"].as_f64().unwrap() <= 1e-9,
            "{r}"
        );
    }
}

#[test]
fn a_controller_that_does_not_fit_is_refused() {
    let out = ndr(&[
        "control",
        "--scenario",
        "bilateral",
        "--controller",
        "smith",
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bilateral: wave"), "{err}");
    let out = ndr(&["control", "--link", "udp"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("paper-static"));
}

#[test]
fn each_announced_change_has_its_peak() {
    let v = json(&[
        "control",
        "--link",
        "adaptive",
        "--family",
        "step",
        "--seeds",
        "1",
        "--duration-s",
        "90",
        "--json",
    ]);
    let seed = &v["rows"][0]["seeds"][0];
    let peaks = seed["change_peaks"].as_array().unwrap();
    assert_eq!(peaks.len() as u64, seed["announced"].as_u64().unwrap());
    assert!(!peaks.is_empty());
    // The +150 ms step at 60 s of the network is announced.
    assert!(
        peaks
            .iter()
            .any(|p| (60.0..62.0).contains(&p["at_s"].as_f64().unwrap())),
        "{peaks:?}"
    );
}
