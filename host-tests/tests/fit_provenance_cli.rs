//! `nanocal fit` records where the model comes from (blob format 4): the stage serial from
//! `--stage-idn` (the controller's `*IDN?` line), the recording's axes, µm, `--fit-date`, and
//! the FNV-1a 64 of the recording's bytes; the same inputs give the same blob byte for byte;
//! bad options are clear errors that leave an existing blob alone.

use nanocal_model::blob;
use nanocal_model::provenance::{fnv1a64, ProvenanceUnit};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const PI_IDN: &str =
    "(c)2015 Physik Instrumente (PI) GmbH & Co. KG, E-727, 0116044408, 13.21.00.09";

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("nanocal-prov-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn training(dir: &Path) -> PathBuf {
    let (train, _) = nanocal::twin::examples::published_1dof(5);
    let tr = dir.join("training.csv");
    nanocal::data::recording::Recording::from_columns(train.columns)
        .unwrap()
        .write_path(&tr)
        .unwrap();
    tr
}

fn fit(rec: &Path, out: &Path, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_nanocal"))
        .arg("fit")
        .arg(rec)
        .arg("-o")
        .arg(out)
        .args(["--published-static", "--blocks", "0"])
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn fit_records_the_stage_date_and_data_and_is_reproducible() {
    let dir = tmp("ok");
    let rec = training(&dir);
    let (a, b) = (dir.join("a.blob"), dir.join("b.blob"));
    let args = ["--stage-idn", PI_IDN, "--fit-date", "2023-11-14T22:13:20Z"];
    let out = fit(&rec, &a, &args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains(
            "provenance: stage serial 0116044408, axes x in µm, fitted 2023-11-14T22:13:20Z"
        ),
        "{text}"
    );
    let bytes = std::fs::read(&a).unwrap();
    assert_eq!(&bytes[4..6], &4u16.to_le_bytes());
    let m = blob::decode(&bytes).unwrap();
    let p = m.provenance();
    assert_eq!(p.stage_serial.unwrap().as_str(), "0116044408");
    assert_eq!(p.axes[0].unwrap().as_str(), "x");
    assert!(p.axes[1].is_none());
    assert_eq!(p.unit, ProvenanceUnit::Um);
    assert_eq!(p.fit_date_s, 1_700_000_000);
    assert_eq!(p.data_fnv64, fnv1a64(&std::fs::read(&rec).unwrap()));
    // the same recording, options and date: the same bytes
    let out = fit(&rec, &b, &args);
    assert!(out.status.success());
    assert_eq!(std::fs::read(&b).unwrap(), bytes);
    // without the stage's identification: no serial, and the output says what that means
    let out = fit(&rec, &b, &["--fit-date", "1700000000"]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout)
        .contains("not recorded (the device will not check the stage)"));
    let m = blob::decode(&std::fs::read(&b).unwrap()).unwrap();
    assert!(m.provenance().stage_serial.is_none());
    assert_eq!(m.provenance().fit_date_s, 1_700_000_000);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_provenance_options_are_clear_errors_and_keep_the_old_blob() {
    let dir = tmp("bad");
    let rec = training(&dir);
    let out_blob = dir.join("m.blob");
    std::fs::write(&out_blob, b"the blob already here").unwrap();
    for (args, words) in [
        (
            ["--stage-idn", "PI E-727 0116044408"],
            "no serial number in it",
        ),
        (["--fit-date", "2023-02-29"], "--fit-date \"2023-02-29\""),
    ] {
        let out = fit(&rec, &out_blob, &args);
        assert!(!out.status.success(), "{args:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(words), "{args:?}: {err}");
        assert_eq!(std::fs::read(&out_blob).unwrap(), b"the blob already here");
    }
    std::fs::remove_dir_all(&dir).ok();
}
