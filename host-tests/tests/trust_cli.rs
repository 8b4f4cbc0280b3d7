//! What a fit knows about itself, through the CLI: `stepwise` and `fit` report MATLAB
//! `stepwisefit`'s statistics, the prediction interval, variance inflation and held-out
//! accuracy; `validate --fit-json` reports the interval's coverage.
//!
//! Reference numbers for the Hald cement data (`data/hald-cement/`) come from GNU Octave 7.3,
//! computed independently of nanocal with the normal equations (fine at this size, and a
//! different method from nanocal's QR):
//!
//! ```octave
//! d = dlmread('data/hald-cement/hald.csv', ',', 1, 0);
//! X = [ones(13,1) d(:,1) d(:,4)]; y = d(:,5);
//! b = X\y; r = y - X*b; dfe = 10; s = sqrt(r'*r/dfe);
//! x = betaincinv(0.05, dfe/2, 0.5); t = sqrt(dfe*(1-x)/x);   % t quantile 0.975, 10 df
//! hw = t*s*sqrt(1 + sum((X/(X'*X)).*X, 2));                   % PI half-width per row
//! % t = 2.2281388519862748; min/median/max(hw) = 6.3304658812401211 6.6541378613347222 7.5302702397226788
//! v = diag(inv(corrcoef(d(:,1:4))));                          % VIF of x1..x4
//! % v = 38.496211490635758 254.4231658509249 46.868386333574087 282.512864788569
//! ```
use std::path::PathBuf;
use std::process::Command;

fn nanocal() -> Command {
    Command::new(env!("CARGO_BIN_EXE_nanocal"))
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("nanocal-trust-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

const HALD: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/hald-cement/hald.csv");

fn run_ok(cmd: &mut Command) -> String {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn rel(a: f64, b: f64) -> f64 {
    (a - b).abs() / b.abs()
}

#[test]
fn stepwise_reports_matlab_statistics_and_the_prediction_interval_on_hald() {
    let dir = tmp("hald");
    let json = dir.join("h.json");
    let text = run_ok(
        nanocal()
            .args(["stepwise", HALD, "--response", "heat", "--json"])
            .arg(&json),
    );
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let f = |k: &str| v[k].as_f64().unwrap();
    // MATLAB's documented stepwisefit(ingredients, heat): se = [0.1384 0.1856 0.1992 0.0486]
    // and the stats of the final model {x1, x4} (stepwisefit's doc page, example "Stepwise
    // regression"); history p-values 0.000576232 (x4) and 1.105281e-06 (x1) as MATLAB's
    // stepwiselm documents for the same two steps on the same data.
    let se = v["se"].as_array().unwrap();
    for (got, want) in se.iter().zip([0.1384, 0.1856, 0.1992, 0.0486]) {
        assert!((got.as_f64().unwrap() - want).abs() < 5e-5, "se {got} vs {want}");
    }
    let h = v["history"].as_array().unwrap();
    assert!(rel(h[0]["p"].as_f64().unwrap(), 0.000576232) < 1e-6);
    assert!(rel(h[1]["p"].as_f64().unwrap(), 1.105281e-06) < 1e-6);
    // the same final statistics as the Octave reference (ms_stepwisefit on Octave 7.3.0)
    assert!(rel(f("SStotal"), 2715.7630769230782) < 1e-12);
    assert!(rel(f("SSresid"), 74.762112156735697) < 1e-10);
    assert!(rel(f("fstat"), 176.62696308188779) < 1e-10);
    assert!(rel(f("model_pval"), 1.5810602318144034e-08) < 1e-8);
    assert!(rel(f("r2"), 0.97247104771693116) < 1e-12);
    assert_eq!((v["df0"].as_u64(), v["dfe"].as_u64()), (Some(2), Some(10)));
    // adjusted R² = 1 − (SSresid/dfe)/(SStotal/(n−1))
    let adj = 1.0 - (74.762112156735697 / 10.0) / (2715.7630769230782 / 12.0);
    assert!(rel(f("r2_adjusted"), adj) < 1e-12, "{}", f("r2_adjusted"));
    assert!(text.contains("adjusted R² 0.966965"), "{text}");
    // the 95 % prediction interval at the rows, against Octave's (module doc)
    let pi = &v["trust"]["prediction_interval_95_half_width"];
    for (k, want) in [
        ("min", 6.3304658812401211),
        ("median", 6.6541378613347222),
        ("max", 7.5302702397226788),
    ] {
        let got = pi[k].as_f64().unwrap();
        assert!(rel(got, want) < 1e-10, "PI {k}: {got} vs {want}");
    }
    // x1 and x4 are nearly independent: no warning
    assert_eq!(v["trust"]["vif"]["warnings"], serde_json::json!([]));
    // held-out: 5 blocks of rows, every row predicted once, worse than the training RMSE
    let ho = &v["trust"]["held_out"];
    assert_eq!(ho["predictions"].as_u64(), Some(13));
    assert_eq!(ho["block_rms"].as_array().unwrap().len(), 5);
    assert!(ho["rms"].as_f64().unwrap() > f("rmse") * 0.9);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn stepwise_warns_in_plain_words_when_columns_carry_the_same_information() {
    let dir = tmp("vif");
    let json = dir.join("h.json");
    // keep all four: the Hald ingredients sum to nearly 100 %, the textbook collinearity
    let text = run_ok(
        nanocal()
            .args([
                "stepwise",
                HALD,
                "--response",
                "heat",
                "--inmodel",
                "x1,x2,x3,x4",
                "--keep",
                "x1,x2,x3,x4",
                "--blocks",
                "0",
                "--json",
            ])
            .arg(&json),
    );
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let cols = v["trust"]["vif"]["columns"].as_array().unwrap();
    // against Octave's diag(inv(corrcoef(X))) (module doc)
    for (c, want) in cols.iter().zip([
        38.496211490635758,
        254.4231658509249,
        46.868386333574087,
        282.512864788569,
    ]) {
        let got = c["vif"].as_f64().unwrap();
        assert!(rel(got, want) < 1e-8, "{}: VIF {got} vs {want}", c["name"]);
    }
    assert!(
        text.contains("warning: columns x2 and x4 carry the same information"),
        "{text}"
    );
    assert!(
        text.contains("warning: columns x1 and x3 carry the same information"),
        "{text}"
    );
    assert!(v["trust"]["held_out"].is_null());
    std::fs::remove_dir_all(&dir).ok();
}
