//! Explain refuses unusable recordings with errors that say what was expected, what was found
//! and where; and works on recordings without commands (several measured channels, thermal only).

use nanocal::explain::{explain, Data, Settings};
use nanocal::recording::Recording;

fn rec(cols: Vec<(&str, Vec<f64>)>) -> Recording {
    Recording::from_columns(cols.into_iter().map(|(n, v)| (n.to_string(), v)).collect()).unwrap()
}

#[test]
fn errors_name_what_and_where() {
    let t: Vec<f64> = (0..100).map(|i| i as f64).collect();
    let no_meas = rec(vec![
        ("t", t.clone()),
        ("cmd_x", t.clone()),
        ("temp_a", vec![20.0; 100]),
    ]);
    let e = Data::from_recording(&no_meas, None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("meas_"), "{e}");

    let mut back = t.clone();
    back[50] = 10.0;
    let bad_t = rec(vec![("t", back), ("meas_x", t.clone())]);
    let e = Data::from_recording(&bad_t, None).unwrap_err().to_string();
    assert!(e.contains("`t`") && e.contains("row"), "{e}");

    let mut nan = t.clone();
    nan[7] = f64::NAN;
    let bad_v = rec(vec![("t", t.clone()), ("meas_x", nan)]);
    let e = Data::from_recording(&bad_v, None).unwrap_err().to_string();
    assert!(e.contains("meas_x") && e.contains("row 8"), "{e}");
}

#[test]
fn thermal_only_channels_without_commands_are_explained_each() {
    // two probes reading a structure that follows one sensor with a 20-minute lag
    let n = 6000;
    let t: Vec<f64> = (0..n).map(|i| 10.0 * i as f64).collect();
    let temp: Vec<f64> = t
        .iter()
        .map(|s| 20.0 + 0.5 * (s / 7200.0).sin() + 0.2 * (s / 2500.0).sin())
        .collect();
    let lagged = nanocal::effects::lag_series(&t, &temp, 1200.0, None);
    let noise = |i: usize, k: f64| 0.002 * ((i as f64 * k).sin() + (i as f64 * 1.7 * k).cos());
    let ch1: Vec<f64> = (0..n)
        .map(|i| 3.0 * (lagged[i] - 20.0) + noise(i, 0.37))
        .collect();
    let ch2: Vec<f64> = (0..n)
        .map(|i| -1.5 * (temp[i] - 20.0) + noise(i, 0.61))
        .collect();
    let r = rec(vec![
        ("t", t),
        ("meas_ch1", ch1),
        ("meas_ch2", ch2),
        ("temp_a", temp),
        ("rpm", vec![0.0; n]),
    ]);
    let d = Data::from_recording(&r, None).unwrap();
    let rep = explain(&d, &Settings::default()).unwrap();
    let names = |ch: &str| {
        rep.channels
            .iter()
            .find(|c| c.channel == ch)
            .unwrap()
            .effects
            .iter()
            .map(|e| e.name)
            .collect::<Vec<_>>()
    };
    assert_eq!(names("ch1"), ["thermal_lag"], "{}", rep.to_text());
    assert!(names("ch2").is_empty(), "{}", rep.to_text());
    let tau = rep.channels[0].effects[0]
        .params
        .iter()
        .find(|p| p.name == "tau_s")
        .unwrap()
        .value;
    assert!((tau - 1200.0).abs() < 0.15 * 1200.0, "τ {tau}");
}
