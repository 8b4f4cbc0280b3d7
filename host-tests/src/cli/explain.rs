//! `nanocal explain`: find, name and model the physics a model or simulation left out.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

use crate::data::recording::Recording;
use crate::explain::{explain, plot, Data, Settings};

/// Arguments of `nanocal explain`.
#[derive(Args, Debug)]
pub struct ExplainArgs {
    /// The recording (CSV, shared layout: t, cmd_<axis>, meas_<axis>, temp_<name>, aux).
    pub recording: PathBuf,
    /// Compare against this simulation of the same rows instead of fitting the published static model.
    #[arg(long)]
    pub simulation: Option<PathBuf>,
    /// Write the findings as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write residual plots before/after (PNG and SVG) into this folder.
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// Minimum BIC drop for an effect to be named (sample size = the independent rows behind
    /// its evidence; 6 = strong evidence).
    #[arg(long, default_value_t = 6.0)]
    pub min_bic_drop: f64,
}

/// Run the subcommand.
pub fn run(args: ExplainArgs) -> Result<()> {
    let start = std::time::Instant::now();
    let rec = Recording::read_path(&args.recording)
        .with_context(|| format!("reading {}", args.recording.display()))?;
    let sim = match &args.simulation {
        Some(p) => {
            Some(Recording::read_path(p).with_context(|| format!("reading {}", p.display()))?)
        }
        None => None,
    };
    let data = Data::from_recording(&rec, sim.as_ref())
        .with_context(|| format!("{}", args.recording.display()))?;
    println!(
        "explain {}: {} rows over {}, {} channel(s), {} temperature(s), aux: {}",
        args.recording.display(),
        data.rows(),
        crate::explain::units::duration(data.duration_s()),
        data.channels.len(),
        data.temps.len(),
        if data.aux.is_empty() {
            "none".to_string()
        } else {
            data.aux
                .iter()
                .map(|a| a.0.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        }
    );
    let settings = Settings {
        min_bic_drop: args.min_bic_drop,
        ..Settings::default()
    };
    let report = explain(&data, &settings)?;
    print!("{}", report.to_text());
    if let Some(p) = &args.json {
        std::fs::write(p, serde_json::to_string_pretty(&report.to_json())?)
            .with_context(|| format!("writing {}", p.display()))?;
        println!("wrote {}", p.display());
    }
    if let Some(dir) = &args.plots {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        for c in &report.channels {
            for p in plot::write_residual_plots(dir, &data, c)? {
                println!("wrote {}", p.display());
            }
        }
    }
    println!("done in {:.2} s", start.elapsed().as_secs_f64());
    Ok(())
}
