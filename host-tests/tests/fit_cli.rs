//! The CLI end to end: stepwise table, fit → blob → validate → report, and clear non-zero
//! exits on bad input.
use std::path::PathBuf;
use std::process::Command;

fn nanocal() -> Command {
    Command::new(env!("CARGO_BIN_EXE_nanocal"))
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("nanocal-cli-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn stepwise_cli_prints_the_matlab_like_table_and_json() {
    let dir = tmp("stepwise");
    let hald = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/hald-cement/hald.csv");
    let json = dir.join("h.json");
    let out = nanocal()
        .args(["stepwise", hald, "--response", "heat", "--json"])
        .arg(&json)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("Final columns included: x1 x4"), "{text}");
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(v["selected"], serde_json::json!(["x1", "x4"]));
    assert!((v["intercept"].as_f64().unwrap() - 103.0974).abs() < 1e-4);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn fit_validate_report_round_trip_on_the_twin() {
    let dir = tmp("roundtrip");
    let (train, val) = nanocal::twin::examples::published_1dof(5);
    let tr = dir.join("training.csv");
    let va = dir.join("validation.csv");
    nanocal::data::recording::Recording::from_columns(train.columns)
        .unwrap()
        .write_path(&tr)
        .unwrap();
    nanocal::data::recording::Recording::from_columns(val.columns)
        .unwrap()
        .write_path(&va)
        .unwrap();
    let blob = dir.join("m.blob");
    let out = nanocal()
        .arg("fit")
        .arg(&tr)
        .arg("-o")
        .arg(&blob)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("axis x:") && text.contains("temp_base"),
        "{text}"
    );
    let json = dir.join("v.json");
    let out = nanocal()
        .arg("validate")
        .arg(&blob)
        .arg(&va)
        .arg("--per-pose")
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let acc = |i: usize| v[i]["max_test_accuracy_um"].as_f64().unwrap();
    assert_eq!(v[0]["compensation"], "no model");
    assert!(
        acc(1) < acc(0) && acc(2) < acc(0),
        "static/adaptive not better: {v}"
    );
    // per compensation: R_s (µm), R_t (µm/h) and every test's per-pose Acc
    for i in 0..3 {
        assert!(v[i]["r_s_um"].as_f64().unwrap() > 0.0);
        assert!(v[i]["r_t_um_per_h"].as_f64().unwrap() > 0.0);
        let tests = v[i]["tests"].as_array().unwrap();
        assert!(!tests.is_empty());
        let poses = tests[0]["poses"].as_array().unwrap();
        let worst = poses
            .iter()
            .map(|p| p["accuracy_um"].as_f64().unwrap())
            .fold(0.0, f64::max);
        assert_eq!(worst, tests[0]["accuracy_um"].as_f64().unwrap());
    }
    let plots = dir.join("plots");
    let out = nanocal()
        .arg("report")
        .arg(&blob)
        .arg(&va)
        .arg("--out")
        .arg(&plots)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for f in [
        "error_vs_position",
        "drift_vs_temperature",
        "accuracy_per_pose",
        "error_over_time",
        "test_accuracy_over_time",
    ] {
        for ext in ["png", "svg"] {
            let p = plots.join(format!("{f}.{ext}"));
            assert!(
                std::fs::metadata(&p)
                    .map(|m| m.len() > 1000)
                    .unwrap_or(false),
                "{} missing",
                p.display()
            );
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_input_exits_non_zero_with_the_line() {
    let dir = tmp("bad");
    let csv = dir.join("bad.csv");
    std::fs::write(&csv, "t,cmd_x,meas_x\n0,0,0\n1,30,abc\n").unwrap();
    let out = nanocal()
        .arg("fit")
        .arg(&csv)
        .arg("-o")
        .arg(dir.join("m.blob"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("line 3") && err.contains("meas_x") && err.contains("abc"),
        "{err}"
    );
    let good = dir.join("good.csv");
    std::fs::write(&good, "a,b\n1,2\n3,4\n5,7\n").unwrap();
    let out = nanocal()
        .args(["stepwise"])
        .arg(&good)
        .args(["--response", "nope"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("nope"), "{err}");
    let out = nanocal()
        .arg("validate")
        .arg(&csv)
        .arg(&csv)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("not a valid model blob"));
    let out = nanocal()
        .arg("fit")
        .arg(&csv)
        .arg("-o")
        .arg(dir.join("m.blob"))
        .args(["--terms", "cubic"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("cubic"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn validate_refuses_a_corrupt_or_truncated_blob_in_words() {
    let dir = tmp("badblob");
    let model = nanocal::papers::published::published_1dof().unwrap();
    let mut bytes = vec![0u8; nanocal_model::blob::MAX_BLOB_LEN];
    let n = nanocal_model::blob::encode(&model, &mut bytes).unwrap();
    bytes.truncate(n);
    let (_, val) = nanocal::twin::examples::published_1dof(5);
    let rec = dir.join("val.csv");
    val.to_recording().unwrap().write_path(&rec).unwrap();
    let cases = [
        ("corrupt.blob", "CRC mismatch", true),
        ("truncated.blob", "length mismatch", false),
    ];
    for (name, words, corrupt) in cases {
        let mut b = bytes.clone();
        if corrupt {
            b[40] ^= 0x01;
        } else {
            b.truncate(20);
        }
        let path = dir.join(name);
        std::fs::write(&path, &b).unwrap();
        let out = nanocal()
            .arg("validate")
            .arg(&path)
            .arg(&rec)
            .env("RUST_BACKTRACE", "0")
            .output()
            .unwrap();
        assert!(!out.status.success(), "{name} was accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("not a valid model blob") && err.contains(words),
            "{name}: {err}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// The published 2-DoF procedure through the CLI, as a campaign would: the twin runs the plan
/// and writes it, `fit` trains Eq. 22, `validate --plan` evaluates each test with the
/// compensation the plan gave it.
#[test]
fn a_published_plan_through_simulate_fit_and_validate() {
    let dir = tmp("plan");
    let ok = |out: std::process::Output| {
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).to_string()
    };
    ok(nanocal()
        .args(["simulate", "--plan", "paper000-2dof", "--seed", "3", "-o"])
        .arg(&dir)
        .output()
        .unwrap());
    let plan: nanocal::data::plan::Plan =
        serde_json::from_slice(&std::fs::read(dir.join("plan.json")).unwrap()).unwrap();
    assert_eq!(plan, nanocal::data::plan::Plan::paper000_2dof());
    let blob = dir.join("eq22.blob");
    let text = ok(nanocal()
        .arg("fit")
        .arg(dir.join("training.csv"))
        .args(["--terms", "eq22", "--fixed", "-o"])
        .arg(&blob)
        .output()
        .unwrap());
    assert!(text.contains("axis x: 10 of 10 candidate terms"), "{text}");
    let json = dir.join("v.json");
    let text = ok(nanocal()
        .arg("validate")
        .arg(&blob)
        .arg(dir.join("validation.csv"))
        .arg("--plan")
        .arg(dir.join("plan.json"))
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap());
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    // the plan alternates no model and static: 21 tests each, the adaptive row has none
    let tests = |i: usize| v[i]["tests"].as_array().unwrap().len();
    assert_eq!((tests(0), tests(1), tests(2)), (21, 21, 0), "{text}");
    let worst = |i: usize| v[i]["max_test_accuracy_um"].as_f64().unwrap();
    assert!(worst(1) < 0.25 * worst(0), "{text}");
    let ids: Vec<u64> = v[1]["tests"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["test"].as_u64().unwrap())
        .collect();
    assert!(
        ids.iter().all(|i| i % 2 == 1),
        "static tests are the odd ones"
    );
    std::fs::remove_dir_all(&dir).ok();
}
