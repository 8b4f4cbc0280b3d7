//! `nanocal report`: plots of a validation (PNG and SVG).

use std::path::PathBuf;

use clap::Args;

use crate::cli::validate::ValidationInputs;
use crate::report::write_report;

/// Validate a model on a recording (no model / static / adaptive KMZ) and write the plots a
/// person looks at: error vs position forward and backward, drift vs temperature, accuracy per
/// pose, error over time — each as PNG and SVG.
#[derive(Args, Debug)]
pub struct ReportArgs {
    /// The model, the recording, and how to validate.
    #[command(flatten)]
    pub inputs: ValidationInputs,
    /// Folder for the plots (created if needed).
    #[arg(long, default_value = "report")]
    pub out: PathBuf,
}

/// Runs `nanocal report`.
pub fn run(args: ReportArgs) -> anyhow::Result<()> {
    let (_, r) = args.inputs.validate_three_ways()?;
    let files = write_report(&args.out, &[&r[0], &r[1], &r[2]])?;
    for f in files {
        println!("wrote {}", f.display());
    }
    Ok(())
}
