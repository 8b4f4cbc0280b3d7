//! Blind-style probes: the real recordings of `data/` changed the way other real
//! recordings differ from them — thinned, cut short, a temperature missing, readings on a
//! coarser grid, glitches, irregular time stamps, the time axis stretched from seconds to
//! weeks — and explain must still say the same physics, in the record's own time unit.

use nanocal::data::recording::Recording;
use nanocal::explain::{explain, Data, Report, Settings};

fn read(rel: &str) -> Vec<(String, Vec<f64>)> {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(rel);
    let rec = Recording::read_path(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    rec.names()
        .iter()
        .map(|n| (n.clone(), rec.column(n).unwrap().to_vec()))
        .collect()
}

fn run(cols: Vec<(String, Vec<f64>)>) -> Report {
    let rec = Recording::from_columns(cols).unwrap();
    explain(
        &Data::from_recording(&rec, None).unwrap(),
        &Settings::default(),
    )
    .unwrap()
}

fn keep_rows(cols: &mut [(String, Vec<f64>)], keep: impl Fn(usize, f64) -> bool) {
    let t = cols.iter().find(|c| c.0 == "t").unwrap().1.clone();
    let rows: Vec<usize> = (0..t.len()).filter(|&i| keep(i, t[i])).collect();
    for c in cols.iter_mut() {
        c.1 = rows.iter().map(|&i| c.1[i]).collect();
    }
}

fn col<'a>(cols: &'a mut [(String, Vec<f64>)], name: &str) -> &'a mut Vec<f64> {
    &mut cols.iter_mut().find(|c| c.0 == name).unwrap().1
}

fn first_param(rep: &Report, name: &str) -> (String, f64) {
    let e = &rep.channels[0].effects[0];
    (
        e.name.to_string(),
        e.param(name).map_or(f64::NAN, |p| p.value),
    )
}

/// A Z-probe log thinned to one reading in five (10 s), the chamber sensor missing, eleven
/// readings 4.3 mm off and two mis-triggers: still a thermal lag of minutes first, the glitches
/// reported where they were put.
#[test]
fn zprobe_thinned_without_a_sensor_and_with_glitches() {
    let mut cols = read("zprobe-drift/TL-Q5MC1-Z.csv");
    keep_rows(&mut cols, |i, _| i % 5 == 0);
    cols.retain(|c| c.0 != "temp_chamber");
    let z = col(&mut cols, "meas_z");
    let mut rows: Vec<usize> = (120..131).collect();
    rows.extend([40, 200]);
    rows.sort_unstable();
    for &i in &rows {
        z[i] += 4300.0;
    }
    let rep = run(cols);
    let text = rep.to_text();
    assert_eq!(rep.channels[0].outliers, rows, "{text}");
    let (name, tau) = first_param(&rep, "tau_s");
    assert_eq!(name, "thermal_lag", "{text}");
    assert!((60.0..1800.0).contains(&tau), "τ {tau} s\n{text}");
}

/// The same physics a hundred times faster (a 28 s record): τ in seconds, told in seconds.
#[test]
fn a_record_of_seconds_is_told_in_seconds() {
    let mut cols = read("zprobe-drift/GX-H8A.csv");
    for v in col(&mut cols, "t").iter_mut() {
        *v /= 100.0;
    }
    let rep = run(cols);
    let text = rep.to_text();
    let (name, tau) = first_param(&rep, "tau_s");
    assert_eq!(name, "thermal_lag", "{text}");
    assert!((0.6..18.0).contains(&tau), "τ {tau} s\n{text}");
    assert!(
        text.contains(" s [time]") && !text.contains(" h [time]"),
        "{text}"
    );
}

/// The piezo's first 5 s only, read on a 0.5 µm grid, with one reading 300 µm off, and the
/// time stamps jittered: hysteresis first, counter-clockwise, ≈ 5 µm, the glitch reported,
/// the floor at least the grid's.
#[test]
fn a_short_coarse_glitchy_piezo_log_is_still_hysteresis() {
    let mut cols = read("piezo-hysteresis/recording.csv");
    keep_rows(&mut cols, |_, t| t < 5.0);
    for (i, v) in col(&mut cols, "t").iter_mut().enumerate() {
        *v += 0.0015 * (((i * 7919) % 13) as f64 / 13.0 - 0.5);
    }
    let m = col(&mut cols, "meas_x");
    for v in m.iter_mut() {
        *v = (*v / 0.5).round() * 0.5;
    }
    m[500] += 300.0;
    let rep = run(cols);
    let text = rep.to_text();
    let c = &rep.channels[0];
    assert_eq!(c.outliers, vec![500], "{text}");
    assert!(
        c.noise_floor.sample_um >= 0.5 / 12f64.sqrt() - 1e-12,
        "{text}"
    );
    let (name, hw) = first_param(&rep, "half_width_nm");
    assert_eq!(name, "hysteresis", "{text}");
    assert!((3500.0..6500.0).contains(&hw), "{hw}\n{text}");
    assert_eq!(first_param(&rep, "loop_sense").1, 1.0);
}

/// One spindle channel with six of its sixteen sensors, thinned to one row in eight and its
/// time axis stretched ten times (a 19-day record): still a thermal lag, its τ stretched too,
/// told in days.
#[test]
fn a_record_of_weeks_with_few_sensors_is_still_a_lag() {
    let mut cols = read("spindle-thermal/recording.csv");
    cols.retain(|c| {
        c.0 == "t"
            || c.0 == "meas_ch1"
            || [
                "temp_t1", "temp_t2", "temp_t4", "temp_t5", "temp_t10", "temp_t11",
            ]
            .contains(&c.0.as_str())
    });
    keep_rows(&mut cols, |i, _| i % 8 == 0);
    for v in col(&mut cols, "t").iter_mut() {
        *v *= 10.0;
    }
    let rep = run(cols);
    let text = rep.to_text();
    let (name, tau) = first_param(&rep, "tau_s");
    assert_eq!(name, "thermal_lag", "{text}");
    assert!(tau > 10.0 * 600.0, "τ {tau} s\n{text}");
    assert!(text.contains(" d [time]"), "{text}");
}
