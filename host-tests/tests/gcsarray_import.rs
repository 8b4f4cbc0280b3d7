//! `nanocal import`: PI data-recorder files (GCSArray text written by PIPython's own
//! `pitools.savegcsarray`, and a `DRR?` reply) to the shared recording layout; malformed files
//! are refused with the line named. Golden files and how they were made:
//! `tests/golden/gcsarray/README.md`.
use std::path::PathBuf;
use std::process::Command;

use nanocal::data::recording::Recording;

fn nanocal() -> Command {
    Command::new(env!("CARGO_BIN_EXE_nanocal"))
}

fn golden(name: &str) -> String {
    format!(
        "{}/tests/golden/gcsarray/{name}",
        env!("CARGO_MANIFEST_DIR")
    )
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("nanocal-import-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn pipython_savegcsarray_file_maps_to_the_recording_layout() {
    let dir = tmp("space");
    let out = dir.join("r.csv");
    let o = nanocal()
        .args(["import", &golden("pipython_qdrr_space.gcs"), "-o"])
        .arg(&out)
        // by number and by the table's NAME from the header
        .args([
            "--map",
            "cmd_x=1",
            "--map",
            "meas_x=Position of axis 1",
            "--map",
            "temp_base=3",
            "--map",
            "volt=4",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rec = Recording::read_path(&out).unwrap();
    assert_eq!(rec.rows(), 12);
    assert_eq!(rec.axes(), vec!["x".to_string()]);
    for i in 0..12 {
        let f = i as f64;
        // SAMPLE_TIME = 0.5 s from the header
        assert_eq!(rec.column("t").unwrap()[i], 0.5 * f);
        assert!((rec.column("cmd_x").unwrap()[i] - 10.0 * f).abs() < 1e-9);
        assert!((rec.meas("x").unwrap()[i] - (10.0 * f + 0.001 * f)).abs() < 1e-9);
        assert!((rec.column("temp_base").unwrap()[i] - (22.0 + 0.01 * f)).abs() < 1e-9);
        assert!((rec.column("volt").unwrap()[i] - (1.0 + 0.5 * f)).abs() < 1e-9);
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn tab_separated_file_and_drr_reply_import() {
    let dir = tmp("tab");
    let out = dir.join("r.csv");
    // no SAMPLE_TIME in PIPython's default header: the user gives it
    let o = nanocal()
        .args(["import", &golden("pipython_tab.gcs"), "-o"])
        .arg(&out)
        .args(["--map", "cmd_x=1", "--map", "meas_x=2", "--map", "temp_a=3"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("no SAMPLE_TIME"), "{err}");
    let o = nanocal()
        .args(["import", &golden("pipython_tab.gcs"), "-o"])
        .arg(&out)
        .args(["--map", "cmd_x=1", "--map", "meas_x=2", "--map", "temp_a=3"])
        .args(["--sample-time-s", "2"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rec = Recording::read_path(&out).unwrap();
    assert_eq!(rec.column("t").unwrap()[3], 6.0);
    assert!((rec.meas("x").unwrap()[11] - 110.011).abs() < 1e-9);
    // a DRR? reply, positions in mm converted to µm
    let o = nanocal()
        .args(["import", &golden("drr_reply.txt"), "-o"])
        .arg(&out)
        .args(["--map", "cmd_y=1", "--map", "meas_y=2", "--to-um", "1000"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rec = Recording::read_path(&out).unwrap();
    assert_eq!(rec.rows(), 4);
    assert!((rec.column("t").unwrap()[2] - 0.0001).abs() < 1e-15);
    assert!((rec.meas("y").unwrap()[3] - 3000.4).abs() < 1e-9);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn malformed_files_and_mappings_are_refused_with_the_line_named() {
    let dir = tmp("bad");
    let run = |text: &str, map: &[&str]| -> String {
        let f = dir.join("in.gcs");
        std::fs::write(&f, text).unwrap();
        let mut c = nanocal();
        c.arg("import").arg(&f).arg("-o").arg(dir.join("o.csv"));
        for m in map {
            c.args(["--map", m]);
        }
        let o = c.output().unwrap();
        assert!(!o.status.success(), "accepted: {text}");
        assert!(
            !dir.join("o.csv").exists(),
            "wrote an output for a refused input"
        );
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let good_header = "# SEPARATOR = 32 \n# DIM = 2 \n# SAMPLE_TIME = 1 \n# END_HEADER \n";
    let map = ["cmd_x=1", "meas_x=2"];
    let e = run(&format!("{good_header}1 2 \n3 \n"), &map);
    assert!(
        e.contains("line 6: expected 2 values (DIM), found 1"),
        "{e}"
    );
    let e = run(&format!("{good_header}1 2 \n3 abc \n"), &map);
    assert!(
        e.contains("line 6: value 2 (table 2): expected a number, found `abc`"),
        "{e}"
    );
    let e = run("# DIM = 2 \n1 2\n", &map);
    assert!(
        e.contains("line 2: expected a `# KEY = value` header line"),
        "{e}"
    );
    let e = run("# DIM = 2 \n# SEPARATOR = x \n# END_HEADER \n", &map);
    assert!(e.contains("line 2: header `SEPARATOR`"), "{e}");
    let e = run("# DIM = 2 \n# NDATA = 5 \n# END_HEADER \n1 2\n", &map);
    assert!(e.contains("header says NDATA = 5, the data have 1"), "{e}");
    let e = run("1 2\n3 4\n", &map);
    assert!(e.contains("no GCSArray header"), "{e}");
    // the mapping must name the reference
    let e = run(&format!("{good_header}1 2 \n"), &["cmd_x=1"]);
    assert!(
        e.contains("name the table that is the reference measurement of axis x: meas_x=TABLE"),
        "{e}"
    );
    let e = run(&format!("{good_header}1 2 \n"), &["cmd_x=1", "meas_x=3"]);
    assert!(e.contains("no table `3`; the file has tables 1, 2"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}
