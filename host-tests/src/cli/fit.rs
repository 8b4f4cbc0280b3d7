//! `nanocal fit`: fit a calibration model to a training recording and write the blob.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

use crate::data::dwell::{dwell_average, DwellOptions};
use crate::data::recording::Recording;
use crate::fit::design::DesignSpec;
use crate::fit::{encode_blob, fit_dwells, FitOptions, FitReport, Selection};
use crate::numerics::stepwise::StepwiseOptions;

/// Fit a calibration model (command as a function of measured position, temperatures, …) to a
/// training recording in the shared layout, and write it as a model blob.
///
/// Each dwell is averaged over its last seconds; candidate terms come from `--terms`; stepwise
/// regression (MATLAB semantics) selects among them unless `--fixed`.
#[derive(Args, Debug)]
pub struct FitArgs {
    /// Training recording (CSV: t, `cmd_<axis>`, `meas_<axis>`, `temp_*`, aux).
    pub recording: PathBuf,
    /// Output model blob.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Candidate terms: poly=N, `poly_<axis>=N`, cross=N, temps, temp_x_pos, aux, direction,
    /// lag=TAU_S (every temperature through a first-order lag), static (= poly=3 temps),
    /// adaptive (= poly=3).
    #[arg(long, default_value = "poly=5 temps temp_x_pos direction")]
    pub terms: String,
    /// Take every candidate term instead of selecting stepwise.
    #[arg(long)]
    pub fixed: bool,
    /// The published static model: cubic + every temperature, fixed (same as `--terms static --fixed`).
    #[arg(long)]
    pub published_static: bool,
    /// Stepwise p-value to enter.
    #[arg(long)]
    pub penter: Option<f64>,
    /// Stepwise p-value to remove.
    #[arg(long)]
    pub premove: Option<f64>,
    /// Average the last this many seconds of each dwell (paper 000: 5 s).
    #[arg(long, default_value_t = 5.0)]
    pub average_last_s: f64,
    /// Model identifier stored in the blob.
    #[arg(long, default_value_t = 0x0003_0001)]
    pub id: u32,
    /// Held-out accuracy over this many contiguous blocks of dwells in time order (the whole
    /// fit rerun without each block); 0: skip.
    #[arg(long, default_value_t = 5)]
    pub blocks: usize,
    /// Write the fit report as JSON here: per axis MATLAB `stepwisefit`'s outputs (b, se, pval,
    /// inmodel, stats, history), the prediction band (what `validate --fit-json` needs for
    /// coverage), VIF, held-out accuracy.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// The stage controller's identification, its reply to `*IDN?` (e.g. "(c)2015 Physik
    /// Instrumente (PI) GmbH & Co. KG, E-727, 0116044408, 13.21.00.09"): the blob records its
    /// serial (the third comma-separated field) and the device refuses to compensate a
    /// controller reporting another (unless its setting allow_other_stage is on). The
    /// recording's CSV has no place for it. Without it the blob records no stage and the
    /// device checks none.
    #[arg(long)]
    pub stage_idn: Option<String>,
    /// The fit's date recorded in the blob, UTC: seconds since 1970 or
    /// YYYY-MM-DD[THH:MM:SS[Z]] (default: now). Give it to make the blob reproducible byte
    /// for byte.
    #[arg(long)]
    pub fit_date: Option<String>,
}

/// Runs `nanocal fit`.
pub fn run(args: FitArgs) -> anyhow::Result<()> {
    let (spec, fixed) = if args.published_static {
        (DesignSpec::published_static(), true)
    } else {
        (DesignSpec::parse(&args.terms)?, args.fixed)
    };
    let bar = crate::cli::validate::spinner(format!("reading {}", args.recording.display()));
    let rec = Recording::read_path(&args.recording)?;
    // checked before the fit's work, so a typo costs nothing
    let fit_date_s = match &args.fit_date {
        Some(t) => crate::fit::provenance::parse_fit_date(t)?,
        None => std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs() as i64),
    };
    if let Some(line) = &args.stage_idn {
        crate::fit::provenance::provenance(b"", &[], Some(line), 0)?;
    }
    let recording_bytes = std::fs::read(&args.recording)
        .with_context(|| format!("reading {}", args.recording.display()))?;
    let selection = if fixed {
        Selection::Fixed
    } else {
        Selection::Stepwise(StepwiseOptions {
            penter: args.penter,
            premove: args.premove,
            ..Default::default()
        })
    };
    let dwell = DwellOptions {
        average_last_s: args.average_last_s,
        ..Default::default()
    };
    let d = dwell_average(&rec, &dwell)?;
    let opts = FitOptions {
        spec,
        selection,
        dwell,
        id: args.id,
    };
    let mut rep =
        fit_dwells(&d, &opts).with_context(|| format!("fitting {}", args.recording.display()))?;
    let provenance = crate::fit::provenance::provenance(
        &recording_bytes,
        &rep.frame.axes,
        args.stage_idn.as_deref(),
        fit_date_s,
    )?;
    rep.model.set_provenance(provenance);
    bar.finish_and_clear();
    print!("{}", summary(&rep));
    println!(
        "{}",
        crate::fit::provenance::describe(rep.model.provenance())
    );
    let held_out = if args.blocks > 0 {
        let bar = crate::cli::validate::spinner(format!(
            "held-out accuracy: refitting without each of {} blocks of time",
            args.blocks
        ));
        let result = crate::fit::held_out_accuracy(&d, &opts, args.blocks);
        bar.finish_and_clear();
        match result {
            Ok(h) => {
                for (ax, h) in rep.frame.axes.iter().zip(&h) {
                    println!(
                        "held-out accuracy, axis {ax} ({} blocks of time, whole fit rerun without each): RMS {:.1} nm, max |error| {:.1} nm over {} dwells (per block RMS: {} nm)",
                        h.blocks,
                        h.rms * 1e3,
                        h.max_abs * 1e3,
                        h.n,
                        h.block_rms
                            .iter()
                            .map(|v| format!("{:.1}", v * 1e3))
                            .collect::<Vec<_>>()
                            .join(", ")
                    );
                }
                Some(h)
            }
            Err(e) => {
                // the fit itself stands: say why there is no held-out figure, keep going
                println!(
                    "held-out accuracy not computed ({} blocks): {e}",
                    args.blocks
                );
                None
            }
        }
    } else {
        None
    };
    if let Some(path) = &args.json {
        let json = report_json(&rep, held_out.as_deref());
        std::fs::write(path, serde_json::to_string_pretty(&json)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let bytes = encode_blob(&rep.model);
    std::fs::write(&args.output, &bytes)
        .with_context(|| format!("writing {}", args.output.display()))?;
    println!(
        "wrote {} ({} bytes, {} terms)",
        args.output.display(),
        bytes.len(),
        rep.model.terms().len()
    );
    Ok(())
}

/// A readable summary of a fit: per axis the selected terms with coefficients ± standard
/// errors in raw units (µm of command per µm^p of position, per °C, …: the papers' form, e.g.
/// paper 000 Table 1), λ, RMS and R², and the training envelope.
pub fn summary(rep: &FitReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(s, "{} training dwells", rep.dwells);
    for ax in &rep.axes {
        let _ = writeln!(
            s,
            "axis {}: {} of {} candidate terms, λ = {:.6} µm, RMS {:.1} nm, R² {:.9}",
            ax.axis,
            ax.selected.iter().filter(|x| **x).count(),
            ax.candidates.len(),
            ax.offset_um,
            ax.rmse_um * 1e3,
            ax.r_squared
        );
        for (j, c) in ax.candidates.iter().enumerate() {
            if ax.selected[j] {
                let _ = writeln!(
                    s,
                    "  {:<20} {:>+14.6e} ± {:.2e} µm",
                    c.name, ax.coeff_um[j], ax.se_um[j]
                );
            }
        }
        match &ax.band {
            Ok(_) => {
                let (lo, med, hi) = ax.pi95_training_um;
                let _ = writeln!(
                    s,
                    "  95 % prediction interval of the correction over the training envelope: ± {:.1} … {:.1} nm (median {:.1} nm)",
                    lo * 1e3,
                    hi * 1e3,
                    med * 1e3
                );
            }
            Err(e) => {
                let _ = writeln!(s, "  no prediction interval: {e}");
            }
        }
        let left: Vec<&str> = ax
            .candidates
            .iter()
            .zip(&ax.selected)
            .filter(|(_, s)| !**s)
            .map(|(c, _)| c.name.as_str())
            .collect();
        if !left.is_empty() {
            let _ = writeln!(s, "  not selected: {}", left.join(", "));
        }
    }
    s += &crate::cli::trust::vif_text(&rep.temp_vif, "temperature");
    let m = &rep.model;
    for (a, name) in rep.frame.axes.iter().enumerate() {
        let (lo, hi) = m.envelope(nanocal_model::Input::Axis(a as u8));
        let _ = writeln!(s, "envelope meas_{name}: {lo:.3} … {hi:.3} µm");
    }
    for (t, name) in rep.frame.temps.iter().enumerate() {
        let (lo, hi) = m.envelope(nanocal_model::Input::Temp(t as u8));
        let _ = writeln!(s, "envelope {name}: {lo:.3} … {hi:.3} °C (model Temp {t})");
    }
    for (k, lag) in m.lags().iter().enumerate() {
        let sensor = &rep.frame.temps[lag.sensor as usize];
        let _ = writeln!(s, "lag filter {k}: {sensor} through τ = {} s", lag.tau_s);
    }
    for (n, name) in rep.frame.aux.iter().enumerate() {
        let (lo, hi) = m.envelope(nanocal_model::Input::Aux(n as u8));
        let _ = writeln!(s, "envelope {name}: {lo:.3} … {hi:.3} (model Aux {n})");
    }
    s
}

/// The provenance as JSON.
fn provenance_json(p: &nanocal_model::Provenance) -> serde_json::Value {
    serde_json::json!({
        "stage_serial": p.stage_serial.map(|s| s.as_str().to_string()),
        "axes": p.axes.iter().flatten().map(|a| a.as_str()).collect::<Vec<_>>(),
        "unit": p.unit.name(),
        "fit_date_utc_s": p.fit_date_s,
        "fit_date_utc": crate::fit::provenance::format_utc(p.fit_date_s),
        "training_data_fnv1a64": format!("{:016x}", p.data_fnv64),
    })
}

/// The fit report as JSON (µm): per axis the terms, MATLAB `stepwisefit`'s outputs when
/// stepwise selected them, the prediction band over the model's own terms, and the summaries.
pub fn report_json(
    rep: &FitReport,
    held_out: Option<&[crate::numerics::uncertainty::HeldOut]>,
) -> serde_json::Value {
    use crate::cli::trust::{held_out_json, spread_json, vif_json};
    let axes: Vec<serde_json::Value> = rep
        .axes
        .iter()
        .enumerate()
        .map(|(a, ax)| {
            let names: Vec<String> = ax.candidates.iter().map(|c| c.name.clone()).collect();
            serde_json::json!({
                "axis": ax.axis,
                "candidates": names,
                "selected": ax.selected,
                "coeff_um": ax.coeff_um,
                "se_um": ax.se_um,
                "offset_um": ax.offset_um,
                "rmse_um": ax.rmse_um,
                "r2": ax.r_squared,
                "stepwisefit": ax.stepwise.as_ref().map(|r| crate::cli::stepwise::to_json(&names, &format!("cmd_{}", ax.axis), r)),
                "prediction_band": ax.band.as_ref().ok(),
                "prediction_band_error": ax.band.as_ref().err().map(|e| e.to_string()),
                "prediction_interval_95_training_um": spread_json(ax.pi95_training_um),
                "held_out_um": held_out.and_then(|h| h.get(a)).map(held_out_json),
            })
        })
        .collect();
    serde_json::json!({
        "model_id": rep.model.id(),
        "provenance": provenance_json(rep.model.provenance()),
        "dwells": rep.dwells,
        "axes": axes,
        "temperature_vif": vif_json(&rep.temp_vif, "temperature"),
        "band_terms": "the model's own terms of each axis, in the blob's order",
    })
}
