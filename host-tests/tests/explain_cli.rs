//! `nanocal simulate` → `nanocal explain --json --plots` end to end, through the binary.

use std::ffi::OsStr;
use std::process::Command;

/// `nanocal explain ARGS`, which must succeed; its standard output.
fn explain_ok(args: &[&OsStr]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_nanocal"))
        .arg("explain")
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).to_string()
}

#[test]
fn simulate_then_explain_writes_json_and_plots() {
    let dir = std::env::temp_dir().join(format!("nanocal-explain-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let csv = dir.join("rec.csv");
    let bin = env!("CARGO_BIN_EXE_nanocal");
    let out = Command::new(bin)
        .args([
            "simulate",
            "--cycles",
            "6",
            "--seed",
            "81",
            "--effect",
            "hysteresis:axis=0,half_width_nm=20,slope_nm=0",
            "-o",
        ])
        .arg(&csv)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json = dir.join("out.json");
    let plots = dir.join("plots");
    let text = explain_ok(&[
        csv.as_os_str(),
        "--json".as_ref(),
        json.as_os_str(),
        "--plots".as_ref(),
        plots.as_os_str(),
    ]);
    assert!(
        text.contains("name: hysteresis") && text.contains("ISO 9283"),
        "{text}"
    );
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert!(v["baseline_rms_nm"].as_f64().unwrap() > 0.0);
    assert_eq!(v["effects"][0]["name"], "hysteresis");
    assert!(v["effects"][0]["params"]["half_width_nm"].as_f64().unwrap() > 15.0);
    assert!(v["unexplained"].as_array().unwrap().is_empty());
    for f in [
        "residual_time_x.png",
        "residual_time_x.svg",
        "residual_position_x.png",
        "residual_position_x.svg",
    ] {
        assert!(plots.join(f).exists(), "{f}");
    }
    // a bad effect name is a clear error, not a panic
    let out = Command::new(bin)
        .args(["simulate", "--effect", "warp_drive:axis=0", "-o"])
        .arg(dir.join("x.csv"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("thermal_lag"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The real 40 s piezo recording through the binary: the header tells its length in seconds
/// (the issue saw "0.0 h"), and a continuous sine revisits no pose, so no ISO 9283 figures.
#[test]
fn a_record_of_seconds_is_introduced_in_seconds() {
    let csv = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data/piezo-hysteresis/recording.csv");
    let text = explain_ok(&[csv.as_os_str()]);
    let header = text.lines().next().unwrap_or_default();
    assert!(
        header.contains(" s, ") && !header.contains(" h,"),
        "{header}"
    );
    assert!(!text.contains("ISO 9283"), "{text}");
}
