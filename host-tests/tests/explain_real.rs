//! Explain on real recordings nobody here produced (`data/` at the repository root, each with a README that
//! says what physics is in it). Every assertion names what the data's README tells us the
//! machine does, so a pass means explain found that physics, not that it reproduced itself.

use nanocal::data::recording::Recording;
use nanocal::explain::{explain, ChannelReport, Data, EffectReport, Report, Settings};

fn data(rel: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../data")
        .join(rel)
}

fn explain_file(rel: &str) -> Report {
    let p = data(rel);
    let rec = Recording::read_path(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    let data = Data::from_recording(&rec, None).unwrap();
    explain(&data, &Settings::default()).unwrap()
}

/// The headline must say which of the two it is, and say it truly: structure that no
/// candidate explains is listed exactly when the headline says it remains.
fn assert_headline_tells_what_remains(c: &ChannelReport, what: &str) {
    let h = c.headline();
    if c.unexplained.is_empty() {
        assert!(
            h.contains("nothing significant remains") && !h.contains("structure remains"),
            "{what}: {h}"
        );
    } else {
        assert!(
            h.contains("structure remains that no candidate explains")
                && !h.contains("nothing significant"),
            "{what}: {h}"
        );
    }
}

/// The values of the searched-range bounds that `name` hit, as the evidence reports them
/// ("tau_s at the bottom of the searched range (99.2): an upper bound").
fn bounds_hit(e: &EffectReport, name: &str) -> Vec<f64> {
    let key = format!("{name} at the ");
    e.evidence
        .match_indices(&key)
        .filter_map(|(i, _)| {
            let rest = &e.evidence[i..];
            let open = rest.find("range (")? + "range (".len();
            let close = open + rest[open..].find(')')?;
            rest[open..close].parse().ok()
        })
        .collect()
}

/// Standard deviation of the second differences / √6: the white-noise level of a series
/// whose drift is smooth, computed here independently of explain.
fn second_difference_noise(v: &[f64]) -> f64 {
    let d2: Vec<f64> = v.windows(3).map(|w| w[2] - 2.0 * w[1] + w[0]).collect();
    let m = d2.iter().sum::<f64>() / d2.len() as f64;
    (d2.iter().map(|x| (x - m).powi(2)).sum::<f64>() / d2.len() as f64).sqrt() / 6f64.sqrt()
}

fn param(e: &EffectReport, name: &str) -> f64 {
    e.param(name)
        .unwrap_or_else(|| panic!("{} has no {name}", e.name))
        .value
}

/// Five inductive Z-probes on a 3D printer through cold, heat-up, soak and cool-down. The
/// README: "the drift follows the bed and nozzle heating with a delay of minutes (the probe
/// sits a few mm above the bed and warms through air and its mount)"; the recorded bed,
/// hotend and chamber temperatures are sample-and-held reports every ~20 s, the trigger
/// height is quantised to 1.25 µm. So the physics is a thermal lag of minutes behind the
/// recorded temperatures — not a drift of unknown origin — and the noise floor is the
/// quantisation's, not tens of nanometres.
#[test]
fn zprobe_drift_is_a_thermal_lag_of_minutes() {
    let dir = data("zprobe-drift");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "csv"))
        .collect();
    files.sort();
    assert_eq!(files.len(), 5, "{}", dir.display());
    for f in files {
        let name = f.file_name().unwrap().to_string_lossy().to_string();
        let rep = explain_file(&format!("zprobe-drift/{name}"));
        let c = &rep.channels[0];
        let text = rep.to_text();
        assert_headline_tells_what_remains(c, &name);
        // …and not inflated: within 1.5× of the larger of step/√12 and the white noise of
        // the readings' second differences (the issue saw 71 nm floors and σ in the thousands)
        let z = Recording::read_path(&f)
            .unwrap()
            .column("meas_z")
            .unwrap()
            .to_vec();
        let independent_um = (1.25 / 12f64.sqrt()).max(second_difference_noise(&z));
        assert!(
            c.noise_floor.sample_um <= 1.5 * independent_um,
            "{name}: floor {} µm, readings' own {independent_um} µm\n{text}",
            c.noise_floor.sample_um
        );
        // readings on a 1.25 µm grid: the floor is at least 1.25/√12 µm
        assert!(
            (c.quant_step_um.unwrap() - 1.25).abs() < 1e-9,
            "{name}\n{text}"
        );
        assert!(
            c.noise_floor.sample_um >= 1.25 / 12f64.sqrt() - 1e-12,
            "{name}\n{text}"
        );
        let first = c
            .effects
            .first()
            .unwrap_or_else(|| panic!("{name}: nothing named\n{text}"));
        assert_ne!(first.name, "unexplained_drift", "{name}\n{text}");
        let lag = c
            .effects
            .iter()
            .find(|e| e.name == "thermal_lag")
            .unwrap_or_else(|| panic!("{name}: no thermal_lag\n{text}"));
        let tau = param(lag, "tau_s");
        assert!(
            (60.0..=30.0 * 60.0).contains(&tau),
            "{name}: main τ {tau} s is not minutes\n{text}"
        );
        // a τ the data determined, not the edge of the search
        assert!(
            bounds_hit(lag, "tau_s")
                .iter()
                .all(|b| (tau - b).abs() > 0.03 * b),
            "{name}: main τ {tau} s sits on a search bound\n{text}"
        );
        // and it predicts held-out blocks better by a good margin
        assert!(
            lag.rms_after_nm < 0.9 * lag.rms_before_nm,
            "{name}: {} → {} nm",
            lag.rms_before_nm,
            lag.rms_after_nm
        );
    }
}

/// A piezo stack under a full-range 1 Hz sine: the README says "rate-independent hysteresis of
/// the piezo ceramic, modelled by its authors with a backlash (play) operator model", loop
/// ≈ 45 µm peak to peak with a half-width of ≈ 5 µm at mid-range. A piezo's displacement lags
/// its drive: a counter-clockwise loop. No temperatures, no dwells: no thermal lag, no creep
/// (the drive never holds a pose), and no ISO 9283 figures (no pose is revisited).
#[test]
fn piezo_hysteresis_is_named_first_with_its_width_and_sense() {
    let rep = explain_file("piezo-hysteresis/recording.csv");
    let text = rep.to_text();
    let c = &rep.channels[0];
    let first = c.effects.first().unwrap_or_else(|| panic!("{text}"));
    assert_eq!(first.name, "hysteresis", "{text}");
    assert_headline_tells_what_remains(c, "piezo");
    let hw = param(first, "half_width_nm");
    assert!((3000.0..7000.0).contains(&hw), "half width {hw} nm\n{text}");
    assert_eq!(param(first, "loop_sense"), 1.0, "{text}");
    assert!(
        first.summary.starts_with("counter-clockwise"),
        "{}",
        first.summary
    );
    assert!(c
        .effects
        .iter()
        .all(|e| e.name != "creep" && e.name != "thermal_lag"));
    assert!(c.iso_before.is_none() && c.iso_after.is_none(), "{text}");
    assert!(first.rms_after_nm < 0.2 * first.rms_before_nm, "{text}");
    // the operators it hands over: thresholds ascending within the half stroke, weights ≥ 0
    let ops = &first.blob.as_ref().unwrap().play;
    assert!(ops
        .windows(2)
        .all(|w| w[0].threshold_um < w[1].threshold_um));
    assert!(ops.iter().all(|o| o.weight > 0.0 && o.threshold_um <= 22.6));
    // a 40 s record is told in seconds
    assert!(!text.contains(" h [time]"), "{text}");
}

/// A machine-tool spindle over 46 h, 16 temperatures, five displacement channels. The
/// README: "the displacement lags the sensor readings"; a linear model in the temperatures
/// leaves 1.6–2.5 µm. So every channel shows a thermal lag, of tens of minutes or more.
#[test]
fn spindle_shows_a_thermal_lag_on_all_five_channels() {
    let rep = explain_file("spindle-thermal/recording.csv");
    let text = rep.to_text();
    assert_eq!(rep.channels.len(), 5);
    let rec = Recording::read_path(data("spindle-thermal/recording.csv")).unwrap();
    assert_eq!(rec.temp_columns().len(), 16, "the README's sixteen sensors");
    for c in &rep.channels {
        assert_headline_tells_what_remains(c, &c.channel);
        let lag = c
            .effects
            .iter()
            .find(|e| e.name == "thermal_lag")
            .unwrap_or_else(|| panic!("{}: no thermal_lag\n{text}", c.channel));
        assert_eq!(c.effects[0].name, "thermal_lag", "{}\n{text}", c.channel);
        let tau = lag.param("tau_s").unwrap();
        assert!(tau.value > 600.0, "{}: τ {} s", c.channel, tau.value);
        assert!(
            tau.sigma.is_finite() && tau.sigma > 0.0,
            "{}: τ needs its σ",
            c.channel
        );
    }
}
