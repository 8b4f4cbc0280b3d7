//! Fitting a calibration model: dwell averages → candidate design → stepwise selection (or a
//! fixed term set) → shared [`Model`] with its training envelope.
//!
//! The model maps a calibrated target position `x` to the command `q` to send, so each output
//! axis regresses the command `cmd_<axis>` on the candidate terms evaluated at the measured
//! position `meas_*` (and temperatures, aux, direction of approach). The regressors are the
//! papers' raw candidates (`x`, `x²`, `x³`, `t_i`, …: [`crate::fit::design`]), so the terms are
//! selected as the papers select them and the coefficients are the papers' (paper 000 Table 1:
//! a_1 … a_3, b_1 … b_4, λ). They go into the blob converted exactly into its centred and
//! scaled basis ([`nanocal_model::ModelBuilder::add_raw_term`]); the intercept is λ.

pub mod design;
pub mod provenance;

use nanocal_model::{Model, ModelError, MAX_AXES};

use crate::data::dwell::{dwell_average, DwellError, DwellOptions, Dwells};
use crate::data::recording::Recording;
use crate::fit::design::{regressors, Candidate, DesignError, DesignFrame, DesignSpec};
use crate::numerics::linalg::{lstsq, LinalgError};
use crate::numerics::stepwise::{stepwise, StepwiseError, StepwiseOptions, StepwiseResult};
use crate::numerics::uncertainty::{
    time_blocks, variance_inflation, HeldOut, PredictionBand, UncertaintyError, Vif,
};

/// Errors of a fit.
#[derive(Debug, thiserror::Error)]
pub enum FitError {
    /// Dwell averaging failed.
    #[error(transparent)]
    Dwell(#[from] DwellError),
    /// The design could not be built.
    #[error(transparent)]
    Design(#[from] DesignError),
    /// Stepwise failed.
    #[error(transparent)]
    Stepwise(#[from] StepwiseError),
    /// Least squares failed.
    #[error(transparent)]
    Linalg(#[from] LinalgError),
    /// The model crate rejected the fitted model.
    #[error("model: {0:?}")]
    Model(ModelError),
    /// The held-out blocks could not be made.
    #[error(transparent)]
    Uncertainty(UncertaintyError),
    /// Too few dwells for the number of candidates.
    #[error("expected more dwells than candidate terms + 1 for axis {axis}: {dwells} dwells, {candidates} candidates")]
    TooFewDwells {
        /// Axis.
        axis: String,
        /// Dwells available.
        dwells: usize,
        /// Candidates.
        candidates: usize,
    },
}

/// How the terms are chosen.
#[derive(Debug, Clone)]
pub enum Selection {
    /// Stepwise selection (MATLAB semantics) among the candidates.
    Stepwise(StepwiseOptions),
    /// Every candidate (e.g. the published static model: cubic + every temperature).
    Fixed,
}

/// Options of a fit.
#[derive(Debug, Clone)]
pub struct FitOptions {
    /// Candidate terms.
    pub spec: DesignSpec,
    /// Selection.
    pub selection: Selection,
    /// Dwell averaging.
    pub dwell: DwellOptions,
    /// Model identifier written into the blob.
    pub id: u32,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            spec: DesignSpec::published_static(),
            selection: Selection::Fixed,
            dwell: DwellOptions::default(),
            id: 0x0003_0001,
        }
    }
}

/// What was fitted on one output axis.
#[derive(Debug, Clone)]
pub struct AxisFit {
    /// Axis name.
    pub axis: String,
    /// The candidates offered.
    pub candidates: Vec<Candidate>,
    /// Which candidates are in the model.
    pub selected: Vec<bool>,
    /// Coefficient per candidate in raw units (0 if not selected): µm of command per unit of
    /// the raw regressor (µm per µm^p of position, per °C of temperature, …).
    pub coeff_um: Vec<f64>,
    /// Standard error per selected candidate (0 if not selected), same units.
    pub se_um: Vec<f64>,
    /// Offset λ (intercept, raw units: the command at zero position and 0 °C), µm.
    pub offset_um: f64,
    /// Residual RMS on the training dwells, µm.
    pub rmse_um: f64,
    /// R² on the training dwells.
    pub r_squared: f64,
    /// The stepwise run, when stepwise selection was used.
    pub stepwise: Option<StepwiseResult>,
    /// Residual sum of squares on the training dwells, µm².
    pub ss_resid_um2: f64,
    /// The prediction interval of the command (= of the correction, the target being known)
    /// over the model's own terms of this axis, in the model's term order
    /// ([`band_regressors`]); an error when it is undefined (no residual degrees of freedom,
    /// rank-deficient design).
    pub band: Result<PredictionBand, UncertaintyError>,
    /// Half-width of the 95 % prediction interval at the training dwells — the training
    /// envelope as measured: (smallest, median, largest), µm (NaN without a band).
    pub pi95_training_um: (f64, f64, f64),
}

/// A fitted model and how it was obtained.
#[derive(Debug, Clone)]
pub struct FitReport {
    /// The model (ready for the blob).
    pub model: Model,
    /// The design frame (axes, channel order).
    pub frame: DesignFrame,
    /// Per output axis.
    pub axes: Vec<AxisFit>,
    /// Number of training dwells.
    pub dwells: usize,
    /// Variance inflation of every temperature channel the design uses, against the others.
    pub temp_vif: Vec<Vif>,
}

/// Fits a model on a raw recording (dwell averaging first).
pub fn fit_recording(rec: &Recording, opts: &FitOptions) -> Result<FitReport, FitError> {
    let d = dwell_average(rec, &opts.dwell)?;
    fit_dwells(&d, opts)
}

/// Fits a model on per-dwell samples.
pub fn fit_dwells(d: &Dwells, opts: &FitOptions) -> Result<FitReport, FitError> {
    let frame = DesignFrame::from_dwells(d, &opts.spec)?;
    let inputs = frame.raw_inputs(d);
    let mut builder = frame.builder().id(opts.id);
    let mut axes = Vec::new();
    for (a, axis) in frame.axes.iter().enumerate() {
        let candidates = frame.candidates(&opts.spec, a);
        if d.len() <= candidates.len() + 1 {
            return Err(FitError::TooFewDwells {
                axis: axis.clone(),
                dwells: d.len(),
                candidates: candidates.len(),
            });
        }
        let x = regressors(&candidates, &inputs);
        let xr: Vec<&[f64]> = x.iter().map(|c| c.as_slice()).collect();
        let y = &d.cmd_um[a];
        let fit = match &opts.selection {
            Selection::Fixed => {
                let ls = lstsq(&xr, y, true)?;
                let se = ls.std_errors();
                let ss_tot = {
                    let m = y.iter().sum::<f64>() / y.len() as f64;
                    y.iter().map(|v| (v - m).powi(2)).sum::<f64>()
                };
                AxisFit {
                    axis: axis.clone(),
                    selected: ls.used.clone(),
                    coeff_um: ls.coeffs.clone(),
                    se_um: se,
                    offset_um: ls.intercept,
                    rmse_um: ls.rmse(),
                    r_squared: 1.0 - ls.rss / ss_tot,
                    candidates,
                    stepwise: None,
                    ss_resid_um2: ls.rss,
                    band: Err(UncertaintyError::RankDeficient(0)),
                    pi95_training_um: (f64::NAN, f64::NAN, f64::NAN),
                }
            }
            Selection::Stepwise(sopts) => {
                let res = stepwise(&xr, y, sopts)?;
                AxisFit {
                    axis: axis.clone(),
                    selected: res.inmodel.clone(),
                    coeff_um: res
                        .b
                        .iter()
                        .zip(&res.inmodel)
                        .map(|(b, &i)| if i { *b } else { 0.0 })
                        .collect(),
                    se_um: res
                        .se
                        .iter()
                        .zip(&res.inmodel)
                        .map(|(s, &i)| if i { *s } else { 0.0 })
                        .collect(),
                    offset_um: res.intercept,
                    rmse_um: res.rmse,
                    r_squared: res.r_squared,
                    candidates,
                    ss_resid_um2: res.ss_resid,
                    stepwise: Some(res),
                    band: Err(UncertaintyError::RankDeficient(0)),
                    pi95_training_um: (f64::NAN, f64::NAN, f64::NAN),
                }
            }
        };
        for (c, (&sel, &coeff)) in fit
            .candidates
            .iter()
            .zip(fit.selected.iter().zip(&fit.coeff_um))
        {
            if sel {
                let t = c.term;
                builder
                    .add_raw_term(t.output, t.powers, t.factor, t.direction, coeff)
                    .map_err(FitError::Model)?;
            }
        }
        builder = builder.offset_um(a, fit.offset_um);
        axes.push(fit);
    }
    let mut model = builder.build().map_err(FitError::Model)?;
    let mut bounds = Vec::with_capacity(axes.len());
    for (a, fit) in axes.iter_mut().enumerate() {
        let rows: Vec<Vec<f64>> = inputs
            .iter()
            .map(|s| band_regressors(&model, a, s))
            .collect();
        let p = rows.first().map_or(0, |r| r.len());
        let cols: Vec<Vec<f64>> = (0..p)
            .map(|j| rows.iter().map(|r| r[j]).collect())
            .collect();
        let refs: Vec<&[f64]> = cols.iter().map(|c| c.as_slice()).collect();
        fit.band = PredictionBand::new(&refs, fit.ss_resid_um2);
        if let Ok(band) = &fit.band {
            let ts = band.t_times_s(0.95);
            let mut hw: Vec<f64> = rows
                .iter()
                .filter_map(|r| band.half_width_with(r, ts).ok())
                .filter(|h| h.is_finite())
                .collect();
            hw.sort_by(f64::total_cmp);
            if !hw.is_empty() {
                fit.pi95_training_um = (hw[0], hw[hw.len() / 2], hw[hw.len() - 1]);
            }
        }
        bounds.push(fit.band.as_ref().ok().and_then(device_bound));
    }
    for (a, bound) in bounds.into_iter().enumerate() {
        model.set_bound(a, bound).map_err(FitError::Model)?;
    }
    let temp_cols: Vec<&[f64]> = frame.temps.iter().filter_map(|n| d.channel(n)).collect();
    let temp_vif = variance_inflation(&frame.temps, &temp_cols);
    Ok(FitReport {
        model,
        frame,
        axes,
        dwells: d.len(),
        temp_vif,
    })
}

/// A fitted model's parameters counted as paper 001 counts them (§VII.A: "78 parameters (45
/// geometric and 33 thermal)"): the selected terms, offsets excluded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ParameterCount {
    /// Position terms (no factor, no sign of approach).
    pub geometric: usize,
    /// Terms with a temperature or a lagged temperature.
    pub thermal: usize,
    /// Everything else (aux inputs, signs of approach, play operators).
    pub other: usize,
}

/// The selected terms of `fit` by kind, offsets excluded ([`ParameterCount`]).
pub fn parameter_count(fit: &FitReport) -> ParameterCount {
    use nanocal_model::Factor;
    let mut n = ParameterCount {
        geometric: 0,
        thermal: 0,
        other: 0,
    };
    for ax in &fit.axes {
        for (c, _) in ax.candidates.iter().zip(&ax.selected).filter(|(_, s)| **s) {
            match (c.term.factor, c.term.direction) {
                (Factor::None, 0) => n.geometric += 1,
                (Factor::Temp(_) | Factor::Lagged(_), _) => n.thermal += 1,
                _ => n.other += 1,
            }
        }
    }
    n
}

/// The regressors of output axis `axis` at `inputs`: the model's own terms of that axis, in the
/// model's order (the columns of [`AxisFit::band`]).
pub fn band_regressors(
    model: &Model,
    axis: usize,
    inputs: &nanocal_model::ScaledInputs,
) -> Vec<f64> {
    model
        .terms()
        .iter()
        .filter(|t| t.output as usize == axis)
        .map(|t| t.value(inputs))
        .collect()
}

/// Held-out accuracy per output axis, by `blocks` contiguous blocks of dwells in time order
/// ([`crate::numerics::uncertainty`] says why not random rows): each block is predicted by the whole
/// procedure — design, selection, fit — run on the other blocks; the error is the recorded
/// command minus the predicted one, µm. A block at either end of the recording is an
/// extrapolation in time (and often in temperature): that is the honest case.
pub fn held_out_accuracy(
    d: &Dwells,
    opts: &FitOptions,
    blocks: usize,
) -> Result<Vec<HeldOut>, FitError> {
    let ranges = time_blocks(d.len(), blocks).map_err(FitError::Uncertainty)?;
    let axes = d.axes.len();
    let mut errors: Vec<Vec<Vec<f64>>> = vec![Vec::new(); axes];
    for &(start, end) in &ranges {
        let train = d.filter(|i| i < start || i >= end);
        let test = d.filter(|i| i >= start && i < end);
        let rep = fit_dwells(&train, opts)?;
        let slow = rep.frame.slow_inputs(&test);
        let mut per_axis = vec![Vec::with_capacity(test.len()); axes];
        for (i, slow_i) in slow.iter().enumerate() {
            let mut x = [0.0; MAX_AXES];
            let mut dir = [0i8; MAX_AXES];
            for a in 0..axes {
                x[a] = test.meas_um[a][i];
                dir[a] = test.dir[a][i];
            }
            let q = rep.model.eval_f64(&x, &dir, slow_i);
            for a in 0..axes {
                per_axis[a].push(test.cmd_um[a][i] - q[a]);
            }
        }
        for (a, e) in per_axis.into_iter().enumerate() {
            errors[a].push(e);
        }
    }
    Ok(errors
        .iter()
        .map(|e| HeldOut::from_block_errors(e))
        .collect())
}

/// What the device needs of `band` to bound the prediction interval ([`nanocal_model::bound`]),
/// in f32; `None` when the band has more regressors than a bound holds
/// ([`nanocal_model::MAX_BOUND_TERMS`]) or its numbers do not fit in f32.
pub fn device_bound(band: &PredictionBand) -> Option<nanocal_model::AxisBound> {
    let p = band.regressors();
    if p > nanocal_model::MAX_BOUND_TERMS {
        return None;
    }
    let t95 = crate::numerics::uncertainty::t_quantile(0.975, band.dfe as f64);
    let f32s = |v: &[f64]| v.iter().map(|x| *x as f32).collect::<Vec<f32>>();
    let r_packed: Vec<f32> = (0..=p)
        .flat_map(|i| (i..=p).map(move |j| (i, j)))
        .map(|(i, j)| band.r[i][j] as f32)
        .collect();
    nanocal_model::AxisBound::new(
        band.s as f32,
        t95 as f32,
        &f32s(&band.mean),
        &f32s(&band.scale),
        &r_packed,
    )
    .ok()
}

/// Writes a model as a blob file.
pub fn encode_blob(model: &Model) -> Vec<u8> {
    let mut buf = vec![0u8; nanocal_model::blob::MAX_BLOB_LEN];
    let n =
        nanocal_model::blob::encode(model, &mut buf).expect("MAX_BLOB_LEN holds any valid model");
    buf.truncate(n);
    buf
}

/// The fitted command for dwell `i` of `d`, by the model's reference f64 evaluation (for checks).
pub fn predict(model: &Model, frame: &DesignFrame, d: &Dwells, i: usize) -> [f64; MAX_AXES] {
    let mut x = [0.0; MAX_AXES];
    let mut dir = [0i8; MAX_AXES];
    for a in 0..frame.axes.len() {
        x[a] = d.meas_um[a][i];
        dir[a] = d.dir[a][i];
    }
    model.eval_f64(&x, &dir, &frame.slow_inputs(d)[i])
}

/// The adaptive model of paper 000, Eq. 14: `q = Σ a_i x^(n1−i+1) + λ_KMZ` — the geometric part
/// of the static model `static_model` (its position terms, coefficients unchanged, not refitted)
/// and an offset that the KMZ re-measures. Thermal and auxiliary terms are dropped and the model
/// declares no temperature or aux input (the device needs no sensor for it); the static offset λ
/// is kept as the starting λ + λ_KMZ until the first KMZ.
pub fn adaptive_from_static(static_model: &Model) -> Result<Model, ModelError> {
    use nanocal_model::{Factor, Input, ModelBuilder};
    let axes = static_model.axes();
    let mut b = ModelBuilder::new(axes, 0, 0)?.id(static_model.id());
    for a in 0..axes {
        let input = Input::Axis(a as u8);
        let (lo, hi) = static_model.envelope(input);
        let (tlo, thi) = static_model.travel_um(a);
        b = b
            .scaling(input, static_model.scaling(input))
            .envelope(input, lo, hi)
            .travel_um(a, tlo, thi)
            .offset_um(a, static_model.offset_um(a))
            .kmz_offset_um(a, static_model.kmz_offset_um(a));
    }
    for t in static_model
        .terms()
        .iter()
        .filter(|t| t.factor == Factor::None)
    {
        b.add_term(*t)?;
    }
    b.build()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nanocal_model::{Factor, Input, ModelBuilder, SlowInputs, Term};

    #[test]
    fn adaptive_keeps_the_static_geometric_part_unchanged() {
        // Eq. 11 → Eq. 14: q = 2 + 0.5·u + 0.1·u³ + 3·T → q = 2 + 0.5·u + 0.1·u³ (+ λ_KMZ)
        let mut b = ModelBuilder::new(1, 1, 0)
            .unwrap()
            .id(7)
            .trained_range(Input::Axis(0), 0.0, 480.0)
            .trained_range(Input::Temp(0), 21.0, 23.0)
            .offset_um(0, 2.0);
        let term = |p: u8, factor, c| Term {
            output: 0,
            powers: [p, 0, 0],
            factor,
            direction: 0,
            coeff: c,
        };
        b.add_term(term(1, Factor::None, 0.5)).unwrap();
        b.add_term(term(3, Factor::None, 0.1)).unwrap();
        b.add_term(term(0, Factor::Temp(0), 3.0)).unwrap();
        let st = b.build().unwrap();
        let mut ad = adaptive_from_static(&st).unwrap();
        assert_eq!(ad.temps(), 0);
        assert_eq!(ad.terms(), &st.terms()[..2]);
        assert_eq!(ad.id(), 7);
        // at u = 0.5 (x = 360 µm): 2 + 0.25 + 0.0125
        let q = ad.eval_f64(&[360.0, 0.0, 0.0], &[1, 0, 0], &SlowInputs::default())[0];
        assert!((q - 2.2625).abs() < 1e-12);
        // KMZ: the command 0 reached 0.3 µm → λ_KMZ moves so that 0.3 µm maps to command 0
        ad.set_kmz_from_reference(
            &[0.0; 3],
            &[0.3, 0.0, 0.0],
            &[1, 0, 0],
            &SlowInputs::default(),
        );
        let q0 = ad.eval_f64(&[0.3, 0.0, 0.0], &[1, 0, 0], &SlowInputs::default())[0];
        assert!(q0.abs() < 1e-12);
    }
}
