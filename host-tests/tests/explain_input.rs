//! Explain refuses unusable recordings with errors that say what was expected, what was found
//! and where; reports what a logger got wrong as data faults with their rows; and works on recordings without commands (several measured channels, thermal only).

use nanocal::data::recording::Recording;
use nanocal::explain::{explain, Data, FaultKind, Settings};

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

    let no_time = rec(vec![("t", vec![f64::NAN; 100]), ("meas_x", t.clone())]);
    let e = Data::from_recording(&no_time, None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("`t`") && e.contains("100 of 100"), "{e}");
}

/// What a logger gets wrong is a data fault with its rows, fitted around — not a refusal, and
/// not physics: a time stamp out of order, a missing reading.
#[test]
fn logging_faults_are_reported_with_their_rows_and_fitted_around() {
    let t: Vec<f64> = (0..100).map(|i| i as f64).collect();
    let wiggle: Vec<f64> = (0..100).map(|i| 0.01 * ((i * 37) % 11) as f64).collect();
    let mut back = t.clone();
    back[50] = 10.0;
    let d =
        Data::from_recording(&rec(vec![("t", back), ("meas_x", wiggle.clone())]), None).unwrap();
    let f = d
        .faults
        .iter()
        .find(|f| f.kind == FaultKind::TimeBackwards)
        .unwrap_or_else(|| panic!("{:?}", d.faults));
    assert_eq!(f.rows, vec![(50, 51)]);
    assert!(d.t_s.windows(2).all(|w| w[1] > w[0]));

    let mut nan = wiggle.clone();
    nan[7] = f64::NAN;
    let d = Data::from_recording(&rec(vec![("t", t.clone()), ("meas_x", nan)]), None).unwrap();
    let f = d
        .faults
        .iter()
        .find(|f| f.kind == FaultKind::Missing)
        .unwrap_or_else(|| panic!("{:?}", d.faults));
    assert_eq!(
        (f.column.as_str(), f.rows_in_words()),
        ("meas_x", "8".to_string())
    );
    assert!(
        d.channels[0].y_um[7].is_nan(),
        "the row is left out of the fit"
    );
    let rep = explain(&d, &Settings::default()).unwrap();
    assert!(
        rep.to_text()
            .contains("readings missing in meas_x (data rows 8)"),
        "{}",
        rep.to_text()
    );
    let json = serde_json::to_value(rep.to_json()).unwrap();
    assert_eq!(json["data_faults"][0]["kind"], "missing");
    assert_eq!(json["data_faults"][0]["rows"][0][0], 8);
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
