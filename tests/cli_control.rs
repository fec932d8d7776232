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
