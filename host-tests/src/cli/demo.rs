//! `nanocal demo`: the whole workflow on the bundled example (the digital twin's simulated
//! 1-DoF stage like the published one): train, fit, validate, before/after table, plots.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};

use crate::design::DesignSpec;
use crate::dwell::{dwell_average, DwellOptions};
use crate::fit::{encode_blob, fit_dwells, FitOptions, Selection};
use crate::recording::Recording;
use crate::report::write_report;
use crate::validate::{comparison_table, validate, Compensation};

/// Run the whole calibration workflow on the bundled example: a simulated 1-DoF stage like the
/// published one (cubic geometric error, four temperature sensors, ≈ 3 h of training at
/// 0:30:480 µm forward/backward, three days of hourly validation at 0, 80, …, 480 µm while the
/// room leaves the training range). Fits the published static model (cubic + every
/// temperature) and the adaptive model (cubic + KMZ offset re-measured hourly at 0 µm),
/// validates both, prints the before/after table and writes recordings, blobs and plots.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Folder for recordings, model blobs and plots (created if needed).
    #[arg(long, default_value = "out/demo")]
    pub out: PathBuf,
    /// Seed of the simulated room and noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Average the last this many seconds of each dwell.
    #[arg(long, default_value_t = 10.0)]
    pub average_last_s: f64,
    /// Minimum interval between KMZ re-measurements at 0 µm, s.
    #[arg(long, default_value_t = 3600.0)]
    pub kmz_interval_s: f64,
}

/// Runs `nanocal demo`.
pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let bar = ProgressBar::new(6);
    bar.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} {msg}").expect("static template"),
    );
    bar.set_message("simulating the stage (digital twin)");
    let (train, val) = crate::twin::examples::published_1dof(args.seed);
    let train = Recording::from_columns(train.columns)?;
    let val = Recording::from_columns(val.columns)?;
    bar.inc(1);
    bar.set_message("writing recordings");
    train.write_path(args.out.join("training.csv"))?;
    val.write_path(args.out.join("validation.csv"))?;
    bar.inc(1);
    bar.set_message("dwell averaging");
    let dwell = DwellOptions {
        average_last_s: args.average_last_s,
        ..Default::default()
    };
    let dt = dwell_average(&train, &dwell)?;
    let dv = dwell_average(&val, &dwell)?;
    bar.inc(1);
    bar.set_message("fitting static and adaptive models");
    let fixed = |spec: DesignSpec, id: u32| FitOptions {
        spec,
        selection: Selection::Fixed,
        dwell,
        id,
    };
    let st = fit_dwells(&dt, &fixed(DesignSpec::published_static(), 0x0003_0001))?;
    let ad = fit_dwells(&dt, &fixed(DesignSpec::published_adaptive(), 0x0003_0002))?;
    std::fs::write(args.out.join("static.blob"), encode_blob(&st.model))?;
    std::fs::write(args.out.join("adaptive.blob"), encode_blob(&ad.model))?;
    bar.inc(1);
    bar.set_message("validating");
    let none = validate(None, &dv, &Compensation::None)?;
    let stat = validate(Some(&st.model), &dv, &Compensation::Static)?;
    let adap = validate(
        Some(&ad.model),
        &dv,
        &Compensation::Adaptive {
            reference_um: vec![0.0],
            interval_s: args.kmz_interval_s,
        },
    )?;
    bar.inc(1);
    bar.set_message("plotting");
    let files = write_report(&args.out, &[&none, &stat, &adap])?;
    bar.inc(1);
    bar.finish_and_clear();

    let hours = |d: &crate::dwell::Dwells| {
        (d.t_end_s.last().unwrap_or(&0.0) - d.t_start_s.first().unwrap_or(&0.0)) / 3600.0
    };
    println!(
        "training: {} rows, {} dwells over {:.1} h; validation: {} rows, {} dwells over {:.1} h, {} tests",
        train.rows(),
        dt.len(),
        hours(&dt),
        val.rows(),
        dv.len(),
        hours(&dv),
        none.tests
    );
    println!(
        "static model: cubic + {} temperatures, training RMS {:.1} nm; adaptive: cubic, KMZ re-measured {} times at 0 µm",
        st.frame.temps.len(),
        st.axes[0].rmse_um * 1e3,
        adap.kmz_updates
    );
    println!();
    print!("{}", comparison_table(&[&none, &stat, &adap]));
    println!("published (Tan, Clévy, Chaillet 2015): no model ≈ 1 µm, static ≈ 400 nm, adaptive KMZ ≈ 100 nm");
    if stat.outside_envelope > 0 {
        println!(
            "{} of {} validation visits had temperatures outside the training envelope",
            stat.outside_envelope, stat.distribution.n
        );
    }
    println!();
    println!(
        "wrote {}/{{training,validation}}.csv, static.blob, adaptive.blob and {} plot files:",
        args.out.display(),
        files.len()
    );
    for f in files {
        println!("  {}", f.display());
    }
    Ok(())
}
