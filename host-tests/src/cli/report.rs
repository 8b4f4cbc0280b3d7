//! `nanocal report`: plots of a validation (PNG and SVG).

use std::path::PathBuf;

use clap::Args;

use crate::cli::validate::{read_dwells, read_model, three_ways};
use crate::report::write_report;

/// Validate a model on a recording (no model / static / adaptive KMZ) and write the plots a
/// person looks at: error vs position forward and backward, drift vs temperature, accuracy per
/// pose, error over time — each as PNG and SVG.
#[derive(Args, Debug)]
pub struct ReportArgs {
    /// Model blob.
    pub model: PathBuf,
    /// Validation recording (CSV).
    pub recording: PathBuf,
    /// Folder for the plots (created if needed).
    #[arg(long, default_value = "report")]
    pub out: PathBuf,
    /// Reference pose for KMZ, µm (one value per axis).
    #[arg(long, value_delimiter = ',', default_value = "0")]
    pub reference_pose_um: Vec<f64>,
    /// Minimum interval between KMZ re-measurements, s.
    #[arg(long, default_value_t = 3600.0)]
    pub kmz_interval_s: f64,
    /// Average the last this many seconds of each dwell.
    #[arg(long, default_value_t = 10.0)]
    pub average_last_s: f64,
}

/// Runs `nanocal report`.
pub fn run(args: ReportArgs) -> anyhow::Result<()> {
    let model = read_model(&args.model)?;
    let d = read_dwells(&args.recording, args.average_last_s)?;
    let r = three_ways(&model, &d, &args.reference_pose_um, args.kmz_interval_s)?;
    let files = write_report(&args.out, &[&r[0], &r[1], &r[2]])?;
    for f in files {
        println!("wrote {}", f.display());
    }
    Ok(())
}
