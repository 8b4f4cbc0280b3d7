//! Locate: structure is found where it is, against a noise floor from the data; structure no
//! candidate explains is reported as unexplained, with its place — never forced into a name.

mod explain_common;
use explain_common::*;

use nanocal::effects::{hysteresis, EffectSpec};

#[test]
fn direction_dependence_is_located_before_it_is_named() {
    let rep = explain_columns(training_1dof(
        vec![EffectSpec::Hysteresis(hysteresis::Params {
            axis: 0,
            half_width_nm: 25.0,
            slope_nm: 0.0,
            ..Default::default()
        })],
        6,
        71,
    ));
    let c = channel(&rep, "x");
    assert!(
        c.located.iter().any(|f| f.dimension == "direction"),
        "{:?}",
        c.located
    );
    // the noise floor comes from the data: ~3 nm interferometer noise sample to sample, ~9 nm
    // positioning scatter per dwell
    assert!(
        (1.5..6.0).contains(&(c.noise_floor.sample_um * 1e3)),
        "{:?}",
        c.noise_floor
    );
    assert!(
        (5.0..16.0).contains(&(c.noise_floor.unit_um * 1e3)),
        "{:?}",
        c.noise_floor
    );
    assert!(c.unexplained.is_empty(), "{:?}", c.unexplained);
}

#[test]
fn a_defect_at_one_position_is_unexplained_and_located() {
    for seed in [72, 73] {
        let mut cols = training_1dof(Vec::new(), 6, seed);
        // a scale defect: +60 nm whenever the stage stands at 240 µm — none of the nine effects
        let cmd = cols.get("cmd_x").unwrap().to_vec();
        let meas = &mut cols.columns.iter_mut().find(|c| c.0 == "meas_x").unwrap().1;
        for (m, c) in meas.iter_mut().zip(&cmd) {
            if *c == 240.0 {
                *m += 0.060;
            }
        }
        let rep = explain_columns(cols);
        // not forced into a name
        assert_names(&rep, &[], "defect at one pose");
        let c = channel(&rep, "x");
        assert!(
            c.unexplained.iter().any(|f| f.place.contains("240")),
            "defect at 240 µm not reported as unexplained\n{}",
            rep.to_text()
        );
        let json = rep.to_json();
        assert!(json
            .unexplained
            .iter()
            .any(|u| u.place.contains("240") && u.rms_nm > 30.0));
    }
}
