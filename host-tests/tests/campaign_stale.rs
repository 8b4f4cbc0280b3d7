//! The model-stale flag on the virtual bench's published campaign (issue 19), through the CLI:
//! `nanocal campaign paper000-1dof --virtual` — the QEMU firmware between the campaign and the
//! twin, with the device's default check (k = 3, extrapolation margin 0.1 °C).
//!
//! Paper 000 §4.3.2: the static model "performs good positioning accuracy … in the first 70 h
//! and deteriorates afterwards … due to the fact that the temperature afterwards changed out
//! of the range of the training phase"; "the adaptive model using KMZ achieves accuracy always
//! better than 100 nm". The twin's room leaves the training range from 60 h after training on
//! (+1.3 °C over 48 h). The campaign must see `MODEL_STALE` rise on the static model between 60
//! and 75 h after the end of training — not before, on no static test of the first 60 h — and
//! never on the adaptive model, whose tests stay within 100 nm; and write `report.html` with
//! the rise in it.
//!
//! The published plan is cut after 22 of its 31 rounds (82.5 h of validation: every round up
//! to the rise and five static tests after it) to keep CI's run near 6 min; the README gives
//! the full published run's figures. Without qemu-system-arm the test is skipped with a loud
//! message, except in CI.

use nanocal::data::plan::Plan;
use nanocal::virtual_bench::qemu_or_skip;
use std::process::Command;

/// Rounds of the published plan the test runs (see the module doc).
const ROUNDS: usize = 22;

#[test]
#[ignore = "7–8 min (the published campaign through QEMU): run with --ignored"]
fn model_stale_rises_on_the_static_model_near_70_h_and_never_on_the_adaptive_one() {
    if !qemu_or_skip(
        "model_stale_rises_on_the_static_model_near_70_h_and_never_on_the_adaptive_one",
    ) {
        return;
    }
    let out = std::env::temp_dir().join(format!("nanocal-campaign-stale-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let json = out.with_extension("json");
    // the child gets a user's environment, not cargo test's: with cargo test's variables the
    // campaign's first management request (read settings) went unanswered in two runs out of
    // two, by hand and with this environment it was answered every time; which variable (or
    // whether the machine's load then) is not pinned down
    let keep: Vec<(String, String)> = std::env::vars()
        .filter(|(k, _)| !k.starts_with("CARGO") && !k.starts_with("RUST"))
        .collect();
    let run = Command::new(env!("CARGO_BIN_EXE_nanocal"))
        .env_clear()
        .envs(keep)
        .args([
            "campaign",
            "paper000-1dof",
            "--virtual",
            "--shorten",
            &format!("67,15,{ROUNDS}"),
            "--no-explain",
            "--out",
        ])
        .arg(&out)
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "campaign failed: {}\n{stdout}",
        String::from_utf8_lossy(&run.stderr)
    );
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();

    let plan = Plan::paper000_1dof();
    assert_eq!(plan.validation.test.cycles, 15, "the published tests");
    let validation_start_s = plan.training.duration_s() + plan.pause_s;
    let events = j["model_stale"]
        .as_array()
        .expect("model_stale in the JSON");
    assert!(!events.is_empty(), "MODEL_STALE never rose:\n{stdout}");
    for e in events {
        assert_eq!(
            e["model"], "static",
            "only the static model goes stale: {e}"
        );
    }
    let first = &events[0];
    let rose_h = (first["rose_s"].as_f64().unwrap() - validation_start_s) / 3600.0;
    assert!(
        (60.0..=75.0).contains(&rose_h),
        "MODEL_STALE first rose {rose_h:.1} h after training (paper 000: ~70 h): {first}"
    );
    assert!(
        first["during"].as_str().unwrap().ends_with("(static)"),
        "{first}"
    );
    assert!(
        first["reasons"]
            .as_str()
            .unwrap()
            .contains("left the training envelope"),
        "{first}"
    );
    // every rise is at or after the first: none on a static test of the first 60 h
    for e in events {
        assert!(e["rose_s"].as_f64().unwrap() >= first["rose_s"].as_f64().unwrap());
    }
    // the adaptive tests, never flagged, stay within paper 000's 100 nm
    let adaptive = j["campaign"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["compensation"] == "adaptive KMZ")
        .expect("adaptive tests");
    let accs: Vec<f64> = adaptive["acc_per_test_um"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(accs.len(), ROUNDS);
    assert!(
        accs.iter().all(|a| *a < 0.100),
        "adaptive Acc per test, µm: {accs:?}"
    );
    assert!(
        stdout.contains("MODEL_STALE on the static model at"),
        "{stdout}"
    );

    // report.html: the rise in it, self-contained
    let html = std::fs::read_to_string(out.join("report.html")).expect("report.html written");
    assert!(html.contains("What the compensator said"));
    assert!(html.contains("MODEL_STALE on the static model at"));
    assert!(html.matches("<svg").count() >= 3, "plots not inline");
    for external in ["src=\"http", "href=\"http", "<link", "<script", "<img"] {
        assert!(!html.contains(external), "external resource `{external}`");
    }
    let _ = std::fs::remove_dir_all(&out);
    let _ = std::fs::remove_file(&json);
}
