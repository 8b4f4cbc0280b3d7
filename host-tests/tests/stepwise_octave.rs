//! Differential test: nanocal's stepwise against the independent Octave implementation of MATLAB
//! `stepwisefit` semantics (`../shared/peers/octave-stepwise/`) on random designs.
//!
//! Needs the reference's scripts (developer machines only; skipped with one line without them) and
//! `octave-cli` (install: `.ci/host.sh`; without it the test fails when `CI=true`, else skips).
#![allow(clippy::needless_range_loop)]

use std::path::{Path, PathBuf};
use std::process::Command;

use nanocal::data::recording::Recording;
use nanocal::numerics::stepwise::{stepwise, Action, StepwiseOptions};

/// The reference's driver: `../shared/peers/octave-stepwise/` beside the repository, or the
/// folder `NANOCAL_OCTAVE_STEPWISE` names (a git worktree elsewhere).
fn oracle() -> PathBuf {
    std::env::var_os("NANOCAL_OCTAVE_STEPWISE")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/peers/octave-stepwise")
        })
        .join("stepwise_oracle.sh")
}

fn octave_available() -> bool {
    Command::new("octave-cli")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Whether the differential test can run here. The oracle's scripts live beside the repository
/// (`../shared/peers/`, on developer machines only): without them the test skips with one line.
/// With them, a missing `octave-cli` fails under `CI=true` (`.ci/host.sh` installs it) and skips
/// otherwise.
fn oracle_ready(test: &str) -> bool {
    if !oracle().is_file() {
        eprintln!(
            "SKIPPED {test}: the Octave stepwise reference ({}) is not on this machine",
            oracle().display()
        );
        return false;
    }
    if !octave_available() {
        assert!(
            std::env::var("CI").map_or(true, |v| v != "true"),
            "octave-cli is missing in CI: run .ci/host.sh to install octave + octave-statistics"
        );
        eprintln!("SKIPPED {test}: octave-cli not found (install it with .ci/host.sh)");
        return false;
    }
    true
}

struct Lcg(u64);
impl Lcg {
    fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64) / ((1u64 << 53) as f64)
    }
    fn normal(&mut self) -> f64 {
        let (u, v) = (self.uniform().max(1e-300), self.uniform());
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
    }
}

/// A random design: columns with different scales and offsets, some correlated, and a response
/// that depends on a random subset with effects of varied strength.
fn design(seed: u64, n: usize, p: usize, noise: f64) -> (Vec<Vec<f64>>, Vec<f64>) {
    let mut r = Lcg(seed);
    let mut x: Vec<Vec<f64>> = Vec::new();
    for j in 0..p {
        let scale = 10f64.powf(3.0 * r.uniform() - 1.0);
        let offset = 100.0 * r.uniform();
        let col: Vec<f64> = if j >= 2 && r.uniform() < 0.3 {
            // correlated with an earlier column
            let src = (r.uniform() * j as f64) as usize;
            let mix = 0.5 + 0.5 * r.uniform();
            (0..n)
                .map(|i| mix * x[src][i] + scale * 0.3 * r.normal())
                .collect()
        } else {
            (0..n).map(|_| offset + scale * r.normal()).collect()
        };
        x.push(col);
    }
    let mut y = vec![0.0; n];
    for col in &x {
        if r.uniform() < 0.4 {
            let sd = (col.iter().map(|v| v * v).sum::<f64>() / n as f64)
                .sqrt()
                .max(1e-9);
            let effect = (r.uniform() - 0.5) * 1.0 / sd * 10f64.powf(-1.5 * r.uniform());
            for i in 0..n {
                y[i] += effect * col[i];
            }
        }
    }
    for v in y.iter_mut() {
        *v += noise * r.normal() + 5.0;
    }
    (x, y)
}

struct Case {
    seed: u64,
    noise: f64,
    n: usize,
    p: usize,
    opts: StepwiseOptions,
    args: Vec<String>,
}

fn cases() -> Vec<Case> {
    let mut v = Vec::new();
    let shapes = [
        (25, 4),
        (40, 8),
        (60, 12),
        (200, 6),
        (500, 15),
        (3000, 20),
        (30, 10),
        (100, 25),
    ];
    for (k, &(n, p)) in shapes.iter().enumerate() {
        for variant in 0..3u64 {
            let seed = 1000 + 17 * k as u64 + variant;
            let (opts, args) = match variant {
                0 => (StepwiseOptions::default(), vec![]),
                1 => (
                    StepwiseOptions {
                        penter: Some(0.1),
                        premove: Some(0.15),
                        ..Default::default()
                    },
                    vec![
                        "penter".into(),
                        "0.1".into(),
                        "premove".into(),
                        "0.15".into(),
                    ],
                ),
                _ => {
                    // start from a given model, keep one column, cap the steps
                    let inm: Vec<usize> = (0..p).filter(|j| j % 3 == 0).collect();
                    let keep = vec![p - 1];
                    let s = |v: &[usize]| {
                        v.iter()
                            .map(|j| (j + 1).to_string())
                            .collect::<Vec<_>>()
                            .join(",")
                    };
                    (
                        StepwiseOptions {
                            inmodel: inm.clone(),
                            keep: keep.clone(),
                            maxiter: Some(6),
                            ..Default::default()
                        },
                        vec![
                            "inmodel".into(),
                            s(&inm),
                            "keep".into(),
                            s(&keep),
                            "maxiter".into(),
                            "6".into(),
                        ],
                    )
                }
            };
            v.push(Case {
                seed,
                noise: 0.2,
                n,
                p,
                opts,
                args,
            });
        }
    }
    // large data with strong effects: several p-values underflow to exactly 0 and tie; MATLAB's
    // `min` takes the lowest index (ranking by |t| would take another path)
    for (k, &(n, p)) in [(20000, 8), (50000, 12)].iter().enumerate() {
        v.push(Case {
            seed: 7000 + k as u64,
            noise: 1e-4,
            n,
            p,
            opts: StepwiseOptions::default(),
            args: vec![],
        });
    }
    v
}

fn close(a: f64, b: f64, rel: f64, scale: f64) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs()).max(scale)
}

fn nums(v: &serde_json::Value) -> Vec<f64> {
    match v {
        serde_json::Value::Array(a) => a.iter().map(|x| x.as_f64().unwrap_or(f64::NAN)).collect(),
        x => vec![x.as_f64().unwrap_or(f64::NAN)],
    }
}

#[test]
fn stepwise_matches_octave_oracle_on_random_designs() {
    if !oracle_ready("stepwise_matches_octave_oracle_on_random_designs") {
        return;
    }
    let dir = std::env::temp_dir().join(format!("nanocal-stepwise-oracle-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cases = cases();
    let mut total_steps = 0;
    let mut removals = 0;
    let mut zero_p_steps = 0;
    for (ci, case) in cases.iter().enumerate() {
        let (x, y) = design(case.seed, case.n, case.p, case.noise);
        let mut cols: Vec<(String, Vec<f64>)> = x
            .iter()
            .enumerate()
            .map(|(j, c)| (format!("c{}", j + 1), c.clone()))
            .collect();
        cols.push(("y".into(), y.clone()));
        let rec = Recording::from_columns(cols).unwrap();
        let csv = dir.join(format!("case{ci}.csv"));
        let json = dir.join(format!("case{ci}.json"));
        rec.write_path(&csv).unwrap();
        let out = Command::new("sh")
            .arg(oracle())
            .arg(&csv)
            .arg(&json)
            .args(&case.args)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "oracle failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let want: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();

        let xr: Vec<&[f64]> = x.iter().map(|c| c.as_slice()).collect();
        let got = stepwise(&xr, &y, &case.opts).unwrap();
        let ctx = format!(
            "case {ci} (seed {}, n {}, p {}, args {:?})",
            case.seed, case.n, case.p, case.args
        );

        let inm: Vec<bool> = want["inmodel"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| b.as_bool().unwrap())
            .collect();
        assert_eq!(got.inmodel, inm, "selected set differs: {ctx}");
        let hist = want["history"].as_array().unwrap();
        assert_eq!(
            got.history.len(),
            hist.len(),
            "number of steps differs: {ctx}"
        );
        for (s, h) in got.history.iter().zip(hist) {
            let idx = h["idx"].as_u64().unwrap() as usize - 1;
            let want_action = if h["action"] == "add" {
                Action::Added(idx)
            } else {
                Action::Removed(idx)
            };
            assert_eq!(s.action, want_action, "path differs: {ctx}");
            if matches!(s.action, Action::Removed(_)) {
                removals += 1;
            }
            total_steps += 1;
            if s.p == 0.0 {
                zero_p_steps += 1;
            }
        }
        let bw = nums(&want["b"]);
        let sew = nums(&want["se"]);
        let bscale = bw.iter().fold(0.0f64, |a, v| a.max(v.abs())) * 1e-6;
        for j in 0..case.p {
            assert!(
                close(got.b[j], bw[j], 1e-9, bscale),
                "b[{j}] {} vs {}: {ctx}",
                got.b[j],
                bw[j]
            );
            assert!(
                close(got.se[j], sew[j], 1e-9, 0.0),
                "se[{j}] {} vs {}: {ctx}",
                got.se[j],
                sew[j]
            );
        }
        let pw = nums(&want["pval"]);
        for j in 0..case.p {
            assert!(
                close(got.pval[j], pw[j], 1e-7, 1e-300),
                "pval[{j}] {} vs {}: {ctx}",
                got.pval[j],
                pw[j]
            );
        }
        let icpt = want["intercept"].as_f64().unwrap();
        assert!(
            close(got.intercept, icpt, 1e-9, 0.0),
            "intercept {} vs {icpt}: {ctx}",
            got.intercept
        );
        let rmse = want["rmse"].as_f64().unwrap();
        assert!(
            close(got.rmse, rmse, 1e-9, 0.0),
            "rmse {} vs {rmse}: {ctx}",
            got.rmse
        );
        let r2 = want["r2"].as_f64().unwrap();
        assert!(
            close(got.r_squared, r2, 1e-9, 1.0),
            "R² {} vs {r2}: {ctx}",
            got.r_squared
        );
        let f = want["fstat"].as_f64().unwrap_or(f64::NAN);
        if f.is_finite() {
            assert!(
                close(got.fstat, f, 1e-8, 0.0),
                "F {} vs {f}: {ctx}",
                got.fstat
            );
        }
        assert_eq!(got.dfe as u64, want["dfe"].as_u64().unwrap(), "{ctx}");
    }
    // the random designs must exercise real paths, including removals
    assert!(
        total_steps >= 2 * cases.len(),
        "only {total_steps} steps over {} cases",
        cases.len()
    );
    assert!(removals > 0, "no case removed a term");
    assert!(
        zero_p_steps >= 2,
        "no steps with p-values underflowing to 0 (ties)"
    );
    eprintln!(
        "{} cases, {total_steps} steps, {removals} removals, {zero_p_steps} steps at p = 0",
        cases.len()
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// Writes `[x y]` as CSV, runs the Octave oracle with `args`, returns its JSON.
fn run_oracle(
    dir: &Path,
    name: &str,
    x: &[Vec<f64>],
    y: &[f64],
    args: &[String],
) -> serde_json::Value {
    let mut cols: Vec<(String, Vec<f64>)> = x
        .iter()
        .enumerate()
        .map(|(j, c)| (format!("c{}", j + 1), c.clone()))
        .collect();
    cols.push(("y".into(), y.to_vec()));
    let csv = dir.join(format!("{name}.csv"));
    let json = dir.join(format!("{name}.json"));
    Recording::from_columns(cols)
        .unwrap()
        .write_path(&csv)
        .unwrap();
    let out = Command::new("sh")
        .arg(oracle())
        .arg(&csv)
        .arg(&json)
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "oracle failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap()
}

/// Degenerate designs: an exactly dependent column, a constant column, rows with NaN, and
/// starts from rank-deficient models (the NaN p-value removal path of MATLAB's `stepnext`).
/// Not covered, because no implementation can agree on it: an exact mathematical tie, e.g.
/// with `d = 2a − b` in the model adding `a` or `b` gives the same model and the same p-value,
/// and the choice falls to rounding (here and in MATLAB alike).
#[test]
fn stepwise_matches_octave_oracle_on_degenerate_designs() {
    if !oracle_ready("stepwise_matches_octave_oracle_on_degenerate_designs") {
        return;
    }
    let dir = std::env::temp_dir().join(format!(
        "nanocal-stepwise-degenerate-{}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    let n = 60;
    let mut r = Lcg(77);
    let a: Vec<f64> = (0..n).map(|_| r.normal()).collect();
    let b: Vec<f64> = (0..n).map(|_| 5.0 + 2.0 * r.normal()).collect();
    let c: Vec<f64> = (0..n).map(|_| r.normal()).collect();
    let d: Vec<f64> = a.iter().zip(&b).map(|(a, b)| 2.0 * a - b).collect();
    let e = vec![3.0; n];
    let mut f: Vec<f64> = (0..n).map(|_| r.normal()).collect();
    f[7] = f64::NAN;
    f[31] = f64::NAN;
    let y: Vec<f64> = (0..n)
        .map(|i| 1.0 + a[i] + 0.5 * b[i] + 0.3 * r.normal())
        .collect();
    let x_dep = vec![a.clone(), b.clone(), c.clone(), d, e.clone(), f.clone()];
    let x_const = vec![a, b, c, e, f];
    // (design, options, oracle arguments)
    type Variant<'a> = (&'a Vec<Vec<f64>>, StepwiseOptions, Vec<String>);
    let variants: Vec<Variant> = vec![
        (&x_const, StepwiseOptions::default(), vec![]),
        (
            &x_dep,
            StepwiseOptions {
                inmodel: vec![0, 1, 3],
                ..Default::default()
            },
            vec!["inmodel".into(), "1,2,4".into()],
        ),
        (
            &x_const,
            StepwiseOptions {
                inmodel: vec![3, 4],
                keep: vec![2],
                ..Default::default()
            },
            vec!["inmodel".into(), "4,5".into(), "keep".into(), "3".into()],
        ),
    ];
    for (k, (x, opts, args)) in variants.iter().enumerate() {
        let want = run_oracle(&dir, &format!("deg{k}"), x, &y, args);
        let xr: Vec<&[f64]> = x.iter().map(|c| c.as_slice()).collect();
        let got = stepwise(&xr, &y, opts).unwrap();
        let ctx = format!("variant {k} {args:?}");
        let inm: Vec<bool> = want["inmodel"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_bool().unwrap())
            .collect();
        assert_eq!(got.inmodel, inm, "{ctx}");
        let hist = want["history"].as_array().unwrap();
        let actions: Vec<Action> = hist
            .iter()
            .map(|h| {
                let i = h["idx"].as_u64().unwrap() as usize - 1;
                if h["action"] == "add" {
                    Action::Added(i)
                } else {
                    Action::Removed(i)
                }
            })
            .collect();
        assert_eq!(
            got.history.iter().map(|s| s.action).collect::<Vec<_>>(),
            actions,
            "{ctx}"
        );
        assert_eq!(
            got.rows_used as u64,
            want["n_used"].as_u64().unwrap(),
            "{ctx}"
        );
        let (bw, sew, pw) = (nums(&want["b"]), nums(&want["se"]), nums(&want["pval"]));
        for j in 0..x.len() {
            assert!(
                close(got.b[j], bw[j], 1e-9, 1e-12),
                "b[{j}] {} vs {}: {ctx}",
                got.b[j],
                bw[j]
            );
            assert!(
                close(got.se[j], sew[j], 1e-9, 1e-12),
                "se[{j}] {} vs {}: {ctx}",
                got.se[j],
                sew[j]
            );
            assert!(
                close(got.pval[j], pw[j], 1e-7, 1e-300),
                "p[{j}] {} vs {}: {ctx}",
                got.pval[j],
                pw[j]
            );
        }
        let rmse = want["rmse"].as_f64().unwrap();
        assert!(
            close(got.rmse, rmse, 1e-9, 0.0),
            "rmse {} vs {rmse}: {ctx}",
            got.rmse
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// MATLAB's documented example, `stepwisefit(ingredients, heat)` on the Hald cement data, against
/// the Octave reference: every output of `stepwisefit` — b, se, pval, inmodel, the final
/// statistics and the history (step, column, p, rmse, df0).
#[test]
fn hald_matches_octave_oracle_in_every_output() {
    if !oracle_ready("hald_matches_octave_oracle_in_every_output") {
        return;
    }
    let dir = std::env::temp_dir().join(format!("nanocal-stepwise-hald-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let rec = Recording::read_path(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../data/hald-cement/hald.csv"
    ))
    .unwrap();
    let x: Vec<Vec<f64>> = ["x1", "x2", "x3", "x4"]
        .iter()
        .map(|c| rec.column(c).unwrap().to_vec())
        .collect();
    let y = rec.column("heat").unwrap().to_vec();
    let want = run_oracle(&dir, "hald", &x, &y, &[]);
    let xr: Vec<&[f64]> = x.iter().map(|c| c.as_slice()).collect();
    let got = stepwise(&xr, &y, &StepwiseOptions::default()).unwrap();
    let near = |a: f64, b: f64, what: &str| {
        assert!(close(a, b, 1e-10, 1e-300), "{what}: {a} vs Octave {b}");
    };
    for (k, name) in [(0, "b"), (1, "se"), (2, "pval"), (3, "tstat")] {
        let w = nums(&want[name]);
        let g = [&got.b, &got.se, &got.pval, &got.tstat][k];
        for j in 0..4 {
            near(g[j], w[j], &format!("{name}[{j}]"));
        }
    }
    let inm: Vec<bool> = want["inmodel"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b.as_bool().unwrap())
        .collect();
    assert_eq!(got.inmodel, inm);
    near(
        got.intercept,
        want["intercept"].as_f64().unwrap(),
        "intercept",
    );
    near(got.rmse, want["rmse"].as_f64().unwrap(), "rmse");
    near(got.r_squared, want["r2"].as_f64().unwrap(), "R²");
    near(got.fstat, want["fstat"].as_f64().unwrap(), "F");
    near(got.fpval, want["model_pval"].as_f64().unwrap(), "p of F");
    near(got.ss_total, want["SStotal"].as_f64().unwrap(), "SStotal");
    near(got.ss_resid, want["SSresid"].as_f64().unwrap(), "SSresid");
    assert_eq!(got.dfe as u64, want["dfe"].as_u64().unwrap());
    assert_eq!(got.df0 as u64, want["df0"].as_u64().unwrap());
    // adjusted R² from Octave's sums of squares
    let n = got.rows_used as f64;
    let adj = 1.0
        - (want["SSresid"].as_f64().unwrap() / want["dfe"].as_f64().unwrap())
            / (want["SStotal"].as_f64().unwrap() / (n - 1.0));
    near(got.r_squared_adjusted, adj, "adjusted R²");
    let hist = want["history"].as_array().unwrap();
    assert_eq!(got.history.len(), hist.len());
    for (s, h) in got.history.iter().zip(hist) {
        let idx = h["idx"].as_u64().unwrap() as usize - 1;
        assert_eq!(s.action, Action::Added(idx));
        near(s.p, h["p"].as_f64().unwrap(), "history p");
        near(s.rmse, h["rmse"].as_f64().unwrap(), "history rmse");
        assert_eq!(s.df0 as u64, h["df0"].as_u64().unwrap());
    }
    std::fs::remove_dir_all(&dir).ok();
}
