//! Stepwise regression on the Hald cement data against MATLAB's documented result.
use nanocal::data::recording::Recording;
use nanocal::numerics::stepwise::{stepwise, Action, StepwiseOptions};

fn hald() -> Recording {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/hald-cement/hald.csv");
    Recording::read_path(path).expect("hald.csv from data/hald-cement")
}

#[test]
fn hald_default_selects_x1_x4_like_matlab() {
    let rec = hald();
    let x: Vec<&[f64]> = ["x1", "x2", "x3", "x4"]
        .iter()
        .map(|c| rec.column(c).unwrap())
        .collect();
    let y = rec.column("heat").unwrap();
    let res = stepwise(&x, y, &StepwiseOptions::default()).unwrap();
    assert_eq!(res.inmodel, vec![true, false, false, true]);
    // MATLAB documentation: b = [1.4400 0.4161 -0.4100 -0.6140], intercept 103.0974, rmse 2.7343
    let want_b = [1.4400, 0.4161, -0.4100, -0.6140];
    for (got, want) in res.b.iter().zip(want_b) {
        assert!((got - want).abs() < 5e-5, "b {got} vs {want}");
    }
    assert!(
        (res.intercept - 103.0974).abs() < 5e-5,
        "intercept {}",
        res.intercept
    );
    assert!((res.rmse - 2.7343).abs() < 5e-5, "rmse {}", res.rmse);
    // MATLAB's path: add x4, add x1 (then nothing enters, nothing leaves)
    let actions: Vec<Action> = res.history.iter().map(|s| s.action).collect();
    assert_eq!(actions, vec![Action::Added(3), Action::Added(0)]);
    assert_eq!(res.dfe, 10);
    assert_eq!(res.df0, 2);
    assert!(
        res.r_squared > 0.97 && res.r_squared < 0.98,
        "R² {}",
        res.r_squared
    );
    assert!(res.fpval < 1e-7);
}

#[test]
fn hald_options_change_the_path() {
    let rec = hald();
    let x: Vec<&[f64]> = ["x1", "x2", "x3", "x4"]
        .iter()
        .map(|c| rec.column(c).unwrap())
        .collect();
    let y = rec.column("heat").unwrap();
    // start from the full model: backward elimination removes x3 then x4 (MATLAB doc example)
    let opts = StepwiseOptions {
        inmodel: vec![0, 1, 2, 3],
        ..Default::default()
    };
    let res = stepwise(&x, y, &opts).unwrap();
    assert_eq!(res.history[0].action, Action::Removed(2));
    assert_eq!(res.inmodel, vec![true, true, false, false]);
    // maxiter 1 stops after the first step and reports the next one
    let opts = StepwiseOptions {
        maxiter: Some(1),
        ..Default::default()
    };
    let res = stepwise(&x, y, &opts).unwrap();
    assert_eq!(res.inmodel, vec![false, false, false, true]);
    assert_eq!(res.nextstep, Some(0));
    // keep x2 in: it never leaves
    let opts = StepwiseOptions {
        inmodel: vec![1],
        keep: vec![1],
        ..Default::default()
    };
    let res = stepwise(&x, y, &opts).unwrap();
    assert!(res.inmodel[1]);
    // bad options
    let opts = StepwiseOptions {
        penter: Some(0.2),
        premove: Some(0.1),
        ..Default::default()
    };
    assert!(stepwise(&x, y, &opts).is_err());
}
