//! `nanocal export-table`: a fitted model as a per-axis, bidirectional error table (CSV).

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

use crate::validate::error_table::{table, to_csv, Conditions};

/// Write a model's correction of one axis as a bidirectional error table: per commanded
/// position, the forward and backward error, with "error = reference − commanded" and the
/// temperatures it holds at stated in the file's header (`crate::validate::error_table`).
#[derive(Args, Debug)]
pub struct ExportTableArgs {
    /// Model blob (from `nanocal fit`).
    pub model: PathBuf,
    /// Output CSV.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Axis to tabulate (1-based, model axis order).
    #[arg(long, default_value_t = 1)]
    pub axis: usize,
    /// Step between positions, µm.
    #[arg(long, default_value_t = 10.0)]
    pub step_um: f64,
    /// First position, µm (default: the start of the training envelope).
    #[arg(long)]
    pub from_um: Option<f64>,
    /// Last position, µm (default: the end of the training envelope).
    #[arg(long)]
    pub to_um: Option<f64>,
    /// Temperatures to hold, °C, one per model temperature input (comma separated; default:
    /// the middle of each training range).
    #[arg(long, value_delimiter = ',')]
    pub temps_c: Option<Vec<f64>>,
    /// Positions of the other axes, µm, one per model axis (comma separated; default: the
    /// middle of each training range).
    #[arg(long, value_delimiter = ',')]
    pub axes_um: Option<Vec<f64>>,
    /// Aux values, one per model aux input (default: the middle of each training range).
    #[arg(long, value_delimiter = ',')]
    pub aux: Option<Vec<f64>>,
}

/// Runs `nanocal export-table`.
pub fn run(args: ExportTableArgs) -> anyhow::Result<()> {
    let model = crate::cli::validate::read_model(&args.model)?;
    if args.axis == 0 {
        anyhow::bail!("--axis: axes are numbered from 1");
    }
    let axis = args.axis - 1;
    let mut at = Conditions::envelope_middle(&model);
    if let Some(t) = args.temps_c {
        at.temps_c = t;
    }
    if let Some(a) = args.axes_um {
        at.axes_um = a;
    }
    if let Some(a) = args.aux {
        at.aux = a;
    }
    let (lo, hi) = if axis < model.axes() {
        model.envelope(nanocal_model::Input::Axis(axis as u8))
    } else {
        (0.0, 0.0)
    };
    let rows = table(
        &model,
        axis,
        args.from_um.unwrap_or(lo),
        args.to_um.unwrap_or(hi),
        args.step_um,
        &at,
    )
    .with_context(|| format!("{}", args.model.display()))?;
    std::fs::write(&args.output, to_csv(&model, axis, &at, &rows))
        .with_context(|| format!("writing {}", args.output.display()))?;
    println!(
        "wrote {} ({} positions, axis {}, temperatures {:?} °C)",
        args.output.display(),
        rows.len(),
        args.axis,
        at.temps_c
    );
    Ok(())
}
