//! Candidate design: a readable spec of which terms may enter the model, mapped 1:1 onto the
//! shared model's [`Term`]s.
//!
//! Candidates are the papers' own regressors, in raw units: the powers of the measured
//! position itself (`x`, `x²`, `x³`: paper 000 Eq. 8, 11–13; and for more axes the monomials of
//! the positions as they are), the temperatures, their products with the position. Regressors
//! are computed by the model crate itself: a skeleton [`Model`] with identity scalings turns raw
//! inputs into [`ScaledInputs`] ([`Model::scale`]) and [`Term::value`] evaluates each candidate
//! ([`DesignFrame::raw_inputs`]). Selection (stepwise) therefore decides on `x²`, not on the
//! square of a centred variable: dropping `u²` with `u = (x − c)/h` is not dropping `x²`, and
//! the selected set would not be the paper's. (Scaling or centring a candidate *column*, with
//! the intercept in the model, changes no selection; stepwise and least squares do that
//! internally.) The fitted raw coefficients are then converted exactly — the binomial expansion
//! of [`nanocal_model::ModelBuilder::add_raw_term`] — into the blob's centred and scaled basis
//! (the skeleton with the training envelope's scalings, [`DesignFrame::builder`]), where the
//! firmware's f32 evaluation keeps its precision.
//!
//! Spec syntax (tokens separated by spaces or commas):
//!
//! | token | meaning |
//! |---|---|
//! | `poly=N` | own-axis polynomial `u, u², …, u^N` on every axis |
//! | `poly_<axis>=N` | the same for one axis (e.g. `poly_x=5`) |
//! | `other_poly=N` | pure powers `v, v², …, v^N` of every *other* axis `v` (coupling without products: paper 000's Eq. 22) |
//! | `cross=N` | monomials of total degree ≤ N that involve another axis (coupling and mixed terms) |
//! | `temps` | linear in every temperature (`temp_*` columns, file order = model Temp index) |
//! | `temp_x_pos` | every temperature × own-axis position (thermal expansion of the moving part) |
//! | `aux` | linear in every auxiliary channel (file order = model Aux index) |
//! | `direction` | a constant step with the sign of approach of the own axis (hysteresis) |
//! | `lag=TAU` | every temperature through a first-order lag of time constant TAU s (thermal lag; the blob declares the lag filters and the firmware runs them) |
//! | `static` | shorthand for the published static model: `poly=3 temps` |
//! | `adaptive` | shorthand for the published adaptive model: `poly=3` (offset re-measured by KMZ) |
//! | `eq22` | shorthand for paper 000's 2-DoF model, Eq. 22 with n1 = n2 = 3: `poly=3 other_poly=3 temps` — `q_x = Σ a_ix x^i + Σ b_ix y^i + Σ c_ix t_i + λ_x`, no x·y products |
//! | `paper001` | paper 001's split, §VII.A "78 parameters (45 geometric and 33 thermal)": per motor 15 geometric monomials and 11 thermal terms (every temperature and the own coordinate × temperature `o`), the shapes of [`nanocal_model::reference::delta_robot_78`] (the paper gives only the counts) |

use nanocal_model::{
    Factor, HysteresisState, Input, LagBank, Model, ModelBuilder, ModelError, ScaledInputs,
    SlowInputs, Term, MAX_AUX, MAX_AXES, MAX_TEMPS,
};

use crate::data::dwell::Dwells;

/// Errors building a design.
#[derive(Debug, thiserror::Error)]
pub enum DesignError {
    /// The spec text could not be read.
    #[error("design spec: expected one of poly=N, poly_<axis>=N, other_poly=N, cross=N, temps, temp_x_pos, aux, direction, lag=TAU_S, static, adaptive, eq22, paper001; found `{0}`")]
    BadToken(String),
    /// An axis named in the spec is not in the data.
    #[error("design spec names axis `{0}`, but the data has axes: {1}")]
    UnknownAxis(String, String),
    /// More inputs than the model can hold.
    #[error("too many {what}: the data has {found}, the shared model holds at most {max}")]
    TooMany {
        /// Which inputs.
        what: &'static str,
        /// Found.
        found: usize,
        /// Maximum.
        max: usize,
    },
    /// The data lack something the design needs.
    #[error("{0}")]
    Data(String),
    /// The model crate rejected the skeleton.
    #[error("model: {0:?}")]
    Model(ModelError),
}

/// A factor of an [`ExtensionTerm`]: a lag filter or play operator counts from the
/// extension's own first one.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ExtensionFactor {
    /// No factor.
    None,
    /// Temperature input `n`.
    Temp(u8),
    /// Aux input `n`.
    Aux(u8),
    /// The extension's lag filter `k`.
    Lagged(u8),
    /// The extension's play operator `k`.
    Play(u8),
}

/// A term shape of an [`Extension`]; the fit sets its coefficient.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ExtensionTerm {
    /// Output axis.
    pub output: u8,
    /// Powers of the positions.
    pub powers: [u8; MAX_AXES],
    /// Factor.
    pub factor: ExtensionFactor,
    /// 0, or 1 + the axis whose sign of approach multiplies the term.
    pub direction: u8,
}

/// Candidate terms beyond the spec's tokens: an effect `explain` found, in the form the blob
/// carries it ([`crate::explain::contract::BlobTerms`]): lag filters, play operators, and term shapes
/// (paper 001 §II step 5: back to step 1 with more sources of inaccuracy in the model).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Extension {
    /// What it models, for people (the effect and its channel).
    pub name: String,
    /// Lag filters: (temperature input, τ in s).
    pub lags: Vec<(u8, f64)>,
    /// Play operators: (axis, threshold in µm), grouped by axis, thresholds ascending.
    pub plays: Vec<(u8, f64)>,
    /// Term shapes.
    pub terms: Vec<ExtensionTerm>,
}

impl Extension {
    /// The extension that carries what explain found (`blob`, its deployable form).
    pub fn from_blob_terms(name: &str, blob: &crate::explain::contract::BlobTerms) -> Self {
        let terms = blob
            .terms
            .iter()
            .map(|t| ExtensionTerm {
                output: t.output,
                powers: t.powers,
                factor: match t.factor {
                    Factor::None => ExtensionFactor::None,
                    Factor::Temp(n) => ExtensionFactor::Temp(n),
                    Factor::Aux(n) => ExtensionFactor::Aux(n),
                    Factor::Lagged(k) => ExtensionFactor::Lagged(k),
                    Factor::Play(k) => ExtensionFactor::Play(k),
                },
                direction: t.direction,
            })
            .collect();
        Extension {
            name: name.to_string(),
            lags: blob.lags.clone(),
            plays: blob.plays.clone(),
            terms,
        }
    }

    fn uses_temps(&self) -> bool {
        !self.lags.is_empty()
            || self
                .terms
                .iter()
                .any(|t| matches!(t.factor, ExtensionFactor::Temp(_)))
    }

    fn uses_aux(&self) -> bool {
        self.terms
            .iter()
            .any(|t| matches!(t.factor, ExtensionFactor::Aux(_)))
    }
}

/// Which candidate terms a fit may use (see the module doc for the text form).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DesignSpec {
    /// Own-axis polynomial order for all axes.
    pub poly_order: u8,
    /// Per-axis overrides of the own-axis order.
    pub poly_order_axis: Vec<(String, u8)>,
    /// Highest pure power of every other axis (Eq. 22's coupling terms; 0: none).
    pub other_order: u8,
    /// Maximum total degree of terms that involve another axis (0: none).
    pub cross_order: u8,
    /// Linear temperature terms.
    pub temps: bool,
    /// Temperature × own position terms.
    pub temp_x_position: bool,
    /// Linear auxiliary terms.
    pub aux: bool,
    /// Direction-of-approach step per axis.
    pub direction: bool,
    /// Lagged temperature terms: every temperature through a first-order lag with this τ, s.
    pub lag_tau_s: Option<f64>,
    /// Paper 001's split: per motor its 15 geometric and 11 thermal terms (token `paper001`).
    pub paper001_split: bool,
    /// Effects found by `explain`, added as they deploy in the blob (no text form).
    pub extensions: Vec<Extension>,
}

impl DesignSpec {
    /// The published static model: cubic in position, linear in every temperature.
    pub fn published_static() -> Self {
        DesignSpec {
            poly_order: 3,
            temps: true,
            ..Default::default()
        }
    }

    /// Paper 000's 2-DoF model, Eq. 22, with n1 = n2 = 3 (the paper does not give the orders;
    /// 3 is its 1-DoF order): own-axis cubic, other-axis cubic (pure powers), every temperature.
    pub fn published_2dof() -> Self {
        DesignSpec {
            poly_order: 3,
            other_order: 3,
            temps: true,
            ..Default::default()
        }
    }

    /// Parses the text form.
    pub fn parse(text: &str) -> Result<Self, DesignError> {
        let mut s = DesignSpec::default();
        for tok in text
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|t| !t.is_empty())
        {
            let bad = || DesignError::BadToken(tok.to_string());
            match tok {
                "temps" => s.temps = true,
                "temp_x_pos" => s.temp_x_position = true,
                "aux" => s.aux = true,
                "direction" => s.direction = true,
                "static" => {
                    s.poly_order = s.poly_order.max(3);
                    s.temps = true;
                }
                "adaptive" => s.poly_order = s.poly_order.max(3),
                "paper001" => {
                    s.paper001_split = true;
                }
                "eq22" => {
                    s.poly_order = s.poly_order.max(3);
                    s.other_order = s.other_order.max(3);
                    s.temps = true;
                }
                _ => {
                    let (k, v) = tok.split_once('=').ok_or_else(bad)?;
                    if k == "lag" {
                        let tau: f64 = v.parse().map_err(|_| bad())?;
                        if !(tau > 0.0 && tau.is_finite()) {
                            return Err(bad());
                        }
                        s.lag_tau_s = Some(tau);
                        continue;
                    }
                    let n: u8 = v.parse().map_err(|_| bad())?;
                    if n > 9 {
                        return Err(bad());
                    }
                    if k == "poly" {
                        s.poly_order = n;
                    } else if k == "other_poly" {
                        s.other_order = n;
                    } else if k == "cross" {
                        s.cross_order = n;
                    } else if let Some(axis) = k.strip_prefix("poly_") {
                        s.poly_order_axis.push((axis.to_string(), n));
                    } else {
                        return Err(bad());
                    }
                }
            }
        }
        Ok(s)
    }

    /// Own-axis order of an axis.
    pub fn order_of(&self, axis: &str) -> u8 {
        self.poly_order_axis
            .iter()
            .rev()
            .find(|(a, _)| a == axis)
            .map_or(self.poly_order, |x| x.1)
    }
}

/// A candidate term: the model term (coefficient 0) and a readable name.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// The term; only its coefficient is left to fit.
    pub term: Term,
    /// A readable name, e.g. `x^3`, `x*y`, `temp_base`, `x*temp_base`, `sign_x`.
    pub name: String,
}

/// The inputs of a design: axes, temperature and aux channels, and the skeleton model with
/// their scalings and training envelope.
#[derive(Debug, Clone)]
pub struct DesignFrame {
    /// Axis names.
    pub axes: Vec<String>,
    /// Temperature columns (model Temp index = position here).
    pub temps: Vec<String>,
    /// Aux columns (model Aux index = position here).
    pub aux: Vec<String>,
    /// Per extension of the spec, its first lag filter and first play operator in the model.
    extension_bases: Vec<(u8, u8)>,
    skeleton: Model,
    /// The same inputs with identity scalings: its [`Model::scale`] gives the raw values.
    raw: Model,
}

fn range(v: &[f64]) -> (f64, f64) {
    v.iter()
        .filter(|x| x.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        })
}

impl DesignFrame {
    /// The frame of training dwells: axis scalings and envelope from the measured positions and
    /// the commanded poses together (a validation at a training pose is inside the envelope
    /// even when drift kept the stage short of it), temperature and aux scalings from their
    /// ranges; travel from the commands ± 5 %. Temperatures and aux
    /// channels are declared only when `spec` uses them.
    pub fn from_dwells(d: &Dwells, spec: &DesignSpec) -> Result<Self, DesignError> {
        for (a, _) in &spec.poly_order_axis {
            if !d.axes.contains(a) {
                return Err(DesignError::UnknownAxis(a.clone(), d.axes.join(", ")));
            }
        }
        if d.axes.len() > MAX_AXES {
            return Err(DesignError::TooMany {
                what: "axes",
                found: d.axes.len(),
                max: MAX_AXES,
            });
        }
        let use_temps = spec.temps
            || spec.temp_x_position
            || spec.lag_tau_s.is_some()
            || spec.paper001_split
            || spec.extensions.iter().any(Extension::uses_temps);
        let temps: Vec<String> = if use_temps {
            d.channels
                .iter()
                .map(|c| c.0.clone())
                .filter(|n| n.starts_with("temp_"))
                .collect()
        } else {
            Vec::new()
        };
        let aux: Vec<String> = if spec.aux || spec.extensions.iter().any(Extension::uses_aux) {
            d.channels
                .iter()
                .map(|c| c.0.clone())
                .filter(|n| !n.starts_with("temp_"))
                .collect()
        } else {
            Vec::new()
        };
        if temps.len() > MAX_TEMPS {
            return Err(DesignError::TooMany {
                what: "temperature channels",
                found: temps.len(),
                max: MAX_TEMPS,
            });
        }
        if aux.len() > MAX_AUX {
            return Err(DesignError::TooMany {
                what: "auxiliary channels",
                found: aux.len(),
                max: MAX_AUX,
            });
        }
        if use_temps && temps.is_empty() {
            return Err(DesignError::Data(
                "the design uses temperatures, but the data has no temp_* column".into(),
            ));
        }
        let mut b =
            ModelBuilder::new(d.axes.len(), temps.len(), aux.len()).map_err(DesignError::Model)?;
        for a in 0..d.axes.len() {
            let (mlo, mhi) = range(&d.meas_um[a]);
            if !mlo.is_finite() {
                return Err(DesignError::Data(format!(
                    "no finite meas_{} value to fit",
                    d.axes[a]
                )));
            }
            let (clo, chi) = range(&d.cmd_um[a]);
            // the nominal training poses are trained even when drift kept the stage short of them
            let (lo, hi) = (mlo.min(clo), mhi.max(chi));
            let margin = 0.05 * (chi - clo).max(1.0);
            b = b.trained_range(Input::Axis(a as u8), lo, hi).travel_um(
                a,
                clo - margin,
                chi + margin,
            );
        }
        for (i, name) in temps.iter().enumerate() {
            let (lo, hi) = range(d.channel(name).expect("listed"));
            b = b.trained_range(Input::Temp(i as u8), lo, hi);
        }
        for (i, name) in aux.iter().enumerate() {
            let (lo, hi) = range(d.channel(name).expect("listed"));
            b = b.trained_range(Input::Aux(i as u8), lo, hi);
        }
        let mut raw =
            ModelBuilder::new(d.axes.len(), temps.len(), aux.len()).map_err(DesignError::Model)?;
        if let Some(tau) = spec.lag_tau_s {
            for i in 0..temps.len() {
                b.lag(i as u8, tau).map_err(DesignError::Model)?;
                raw.lag(i as u8, tau).map_err(DesignError::Model)?;
            }
        }
        let mut extension_bases = Vec::new();
        let mut lags = if spec.lag_tau_s.is_some() {
            temps.len() as u8
        } else {
            0
        };
        let mut plays = 0u8;
        for e in &spec.extensions {
            extension_bases.push((lags, plays));
            for &(sensor, tau) in &e.lags {
                if usize::from(sensor) >= temps.len() {
                    return Err(DesignError::Data(format!(
                        "{}: a lag filter on temperature {sensor}, the data has {}",
                        e.name,
                        temps.len()
                    )));
                }
                b.lag(sensor, tau).map_err(DesignError::Model)?;
                raw.lag(sensor, tau).map_err(DesignError::Model)?;
                lags += 1;
            }
            for &(axis, r) in &e.plays {
                b.play(axis, r).map_err(DesignError::Model)?;
                raw.play(axis, r).map_err(DesignError::Model)?;
                plays += 1;
            }
        }
        let skeleton = b.build().map_err(DesignError::Model)?;
        let raw = raw.build().map_err(DesignError::Model)?;
        Ok(DesignFrame {
            axes: d.axes.clone(),
            temps,
            aux,
            extension_bases,
            skeleton,
            raw,
        })
    }

    /// A builder with the frame's scalings, envelope and travel, to receive fitted terms.
    pub fn builder(&self) -> ModelBuilder {
        let m = &self.skeleton;
        let mut b = ModelBuilder::new(m.axes(), m.temps(), m.aux()).expect("skeleton is valid");
        let inputs = (0..m.axes())
            .map(|a| Input::Axis(a as u8))
            .chain((0..m.temps()).map(|t| Input::Temp(t as u8)))
            .chain((0..m.aux()).map(|n| Input::Aux(n as u8)));
        for input in inputs {
            let (lo, hi) = m.envelope(input);
            b = b.scaling(input, m.scaling(input)).envelope(input, lo, hi);
        }
        for a in 0..m.axes() {
            let (lo, hi) = m.travel_um(a);
            b = b.travel_um(a, lo, hi);
        }
        for spec in m.lags() {
            b.lag(spec.sensor, spec.tau_s)
                .expect("skeleton's lags are valid");
        }
        for spec in m.play_operators() {
            b.play(spec.axis, spec.threshold_um)
                .expect("skeleton's play operators are valid");
        }
        b
    }

    /// Candidate terms for output axis `output` under `spec`, in a fixed order: own polynomial
    /// by degree, pure powers of the other axes, cross terms by total degree (each monomial
    /// once), direction, temperatures, temperature × position, lagged temperatures, aux.
    pub fn candidates(&self, spec: &DesignSpec, output: usize) -> Vec<Candidate> {
        let k = self.axes.len();
        let mut out = Vec::new();
        let term = |powers: [u8; MAX_AXES], factor: Factor, direction: u8| Term {
            output: output as u8,
            powers,
            factor,
            direction,
            coeff: 0.0,
        };
        let mono_name = |powers: &[u8; MAX_AXES]| -> String {
            let parts: Vec<String> = (0..k)
                .filter(|&a| powers[a] > 0)
                .map(|a| {
                    if powers[a] == 1 {
                        self.axes[a].clone()
                    } else {
                        format!("{}^{}", self.axes[a], powers[a])
                    }
                })
                .collect();
            parts.join("*")
        };
        let own = self.axes[output].as_str();
        for p in 1..=spec.order_of(own) {
            let mut powers = [0u8; MAX_AXES];
            powers[output] = p;
            out.push(Candidate {
                term: term(powers, Factor::None, 0),
                name: mono_name(&powers),
            });
        }
        let add_monomial = |out: &mut Vec<Candidate>, powers: [u8; MAX_AXES]| {
            let same = |c: &Candidate| {
                c.term.powers == powers && c.term.factor == Factor::None && c.term.direction == 0
            };
            if !out.iter().any(same) {
                out.push(Candidate {
                    term: term(powers, Factor::None, 0),
                    name: mono_name(&powers),
                });
            }
        };
        for other in (0..k).filter(|&b| b != output) {
            for p in 1..=spec.other_order {
                let mut powers = [0u8; MAX_AXES];
                powers[other] = p;
                add_monomial(&mut out, powers);
            }
        }
        if spec.cross_order > 0 && k > 1 {
            for deg in 1..=spec.cross_order {
                for powers in monomials(k, deg) {
                    if (0..k).any(|a| a != output && powers[a] > 0) {
                        add_monomial(&mut out, powers);
                    }
                }
            }
        }
        if spec.direction {
            out.push(Candidate {
                term: term([0; MAX_AXES], Factor::None, output as u8 + 1),
                name: format!("sign_{own}"),
            });
        }
        if spec.temps {
            for (i, name) in self.temps.iter().enumerate() {
                out.push(Candidate {
                    term: term([0; MAX_AXES], Factor::Temp(i as u8), 0),
                    name: name.clone(),
                });
            }
        }
        if spec.temp_x_position {
            let mut powers = [0u8; MAX_AXES];
            powers[output] = 1;
            for (i, name) in self.temps.iter().enumerate() {
                out.push(Candidate {
                    term: term(powers, Factor::Temp(i as u8), 0),
                    name: format!("{own}*{name}"),
                });
            }
        }
        if let Some(tau) = spec.lag_tau_s {
            for (k, lag) in self
                .skeleton
                .lags()
                .iter()
                .enumerate()
                .take(self.temps.len())
            {
                out.push(Candidate {
                    term: term([0; MAX_AXES], Factor::Lagged(k as u8), 0),
                    name: format!("lag({}, {tau} s)", self.temps[lag.sensor as usize]),
                });
            }
        }
        if spec.aux {
            for (i, name) in self.aux.iter().enumerate() {
                out.push(Candidate {
                    term: term([0; MAX_AXES], Factor::Aux(i as u8), 0),
                    name: name.clone(),
                });
            }
        }
        for (e, &(lag0, play0)) in spec.extensions.iter().zip(&self.extension_bases) {
            for t in e.terms.iter().filter(|t| usize::from(t.output) == output) {
                let (factor, what) = match t.factor {
                    ExtensionFactor::None => (Factor::None, String::new()),
                    ExtensionFactor::Temp(n) => (
                        Factor::Temp(n),
                        self.temps.get(usize::from(n)).cloned().unwrap_or_default(),
                    ),
                    ExtensionFactor::Aux(n) => (
                        Factor::Aux(n),
                        self.aux.get(usize::from(n)).cloned().unwrap_or_default(),
                    ),
                    ExtensionFactor::Lagged(k) => {
                        let (sensor, tau) = e.lags[usize::from(k)];
                        let name = &self.temps[usize::from(sensor)];
                        (Factor::Lagged(lag0 + k), format!("lag({name}, {tau:.0} s)"))
                    }
                    ExtensionFactor::Play(k) => {
                        let (axis, r) = e.plays[usize::from(k)];
                        let name = &self.axes[usize::from(axis)];
                        (Factor::Play(play0 + k), format!("play({name}, {r:.4} µm)"))
                    }
                };
                let shape = term(t.powers, factor, t.direction);
                if out.iter().any(|c| c.term.same_shape(&shape)) {
                    continue;
                }
                let mut parts: Vec<String> = Vec::new();
                let mono = mono_name(&t.powers);
                if !mono.is_empty() {
                    parts.push(mono);
                }
                if !what.is_empty() {
                    parts.push(what);
                }
                if t.direction > 0 {
                    parts.push(format!("sign_{}", self.axes[usize::from(t.direction - 1)]));
                }
                out.push(Candidate {
                    term: shape,
                    name: parts.join("*"),
                });
            }
        }
        if spec.paper001_split {
            use nanocal_model::reference::{delta_robot_78_geometric, delta_robot_78_interaction};
            for powers in delta_robot_78_geometric(output) {
                add_monomial(&mut out, powers);
            }
            let mut push_unique = |term: Term, name: String| {
                if !out.iter().any(|c| c.term.same_shape(&term)) {
                    out.push(Candidate { term, name });
                }
            };
            for (i, name) in self.temps.iter().enumerate() {
                push_unique(term([0; MAX_AXES], Factor::Temp(i as u8), 0), name.clone());
            }
            let (powers, factor) = delta_robot_78_interaction(output);
            if let Factor::Temp(t) = factor {
                if let Some(name) = self.temps.get(t as usize) {
                    push_unique(
                        term(powers, factor, 0),
                        format!("{}*{name}", mono_name(&powers)),
                    );
                }
            }
        }
        out
    }

    /// Slow inputs of every dwell (temperatures and aux in model index order; the outputs of
    /// the declared lag filters from the model crate's [`LagBank`], run over the dwells in time
    /// order — exact for temperatures held between dwells).
    pub fn slow_inputs(&self, d: &Dwells) -> Vec<SlowInputs> {
        let mut bank = LagBank::new(self.skeleton.lags());
        (0..d.len())
            .map(|i| {
                let mut s = SlowInputs::default();
                for (t, name) in self.temps.iter().enumerate() {
                    s.temps_c[t] = d.channel(name).map_or(f64::NAN, |c| c[i]);
                }
                for (n, name) in self.aux.iter().enumerate() {
                    s.aux[n] = d.channel(name).map_or(f64::NAN, |c| c[i]);
                }
                let dt_s = if i == 0 {
                    0.0
                } else {
                    d.t_end_s[i] - d.t_end_s[i - 1]
                };
                let temps_c = s.temps_c;
                bank.update(&temps_c, dt_s, &mut s.lagged_c);
                s
            })
            .collect()
    }

    /// Raw inputs of every dwell (positions in µm, temperatures in °C, …), in the form
    /// [`Term::value`] reads: the regressors of the candidates as the papers write them.
    pub fn raw_inputs(&self, d: &Dwells) -> Vec<ScaledInputs> {
        self.inputs_by(&self.raw, d)
    }

    /// Inputs of every dwell by `model`'s scalings; its play operators (if any) run over the
    /// dwells in time order, fed by the calibrated (measured) positions.
    fn inputs_by(&self, model: &Model, d: &Dwells) -> Vec<ScaledInputs> {
        let slow = self.slow_inputs(d);
        let mut hyst = HysteresisState::<f64>::new();
        (0..d.len())
            .map(|i| {
                let mut x = [0.0; MAX_AXES];
                let mut dir = [0i8; MAX_AXES];
                for a in 0..self.axes.len() {
                    x[a] = d.meas_um[a][i];
                    dir[a] = d.dir[a][i];
                }
                model.scale_with_state(&x, &dir, &slow[i], &mut hyst)
            })
            .collect()
    }
}

/// Regressor columns of `candidates` at `inputs`, by the model's own [`Term::value`].
pub fn regressors(candidates: &[Candidate], inputs: &[ScaledInputs]) -> Vec<Vec<f64>> {
    candidates
        .iter()
        .map(|c| inputs.iter().map(|s| c.term.value(s)).collect())
        .collect()
}

/// All exponent vectors over `k` axes with total degree `deg`, in lexicographic order.
fn monomials(k: usize, deg: u8) -> Vec<[u8; MAX_AXES]> {
    let mut out = Vec::new();
    let mut p = [0u8; MAX_AXES];
    fn rec(a: usize, k: usize, left: u8, p: &mut [u8; MAX_AXES], out: &mut Vec<[u8; MAX_AXES]>) {
        if a == k - 1 {
            p[a] = left;
            out.push(*p);
            return;
        }
        for v in (0..=left).rev() {
            p[a] = v;
            rec(a + 1, k, left - v, p, out);
        }
        p[a] = 0;
    }
    rec(0, k, deg, &mut p, &mut out);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spec_parses_and_rejects() {
        let s = DesignSpec::parse("poly=3, temps temp_x_pos cross=2 poly_y=5 direction").unwrap();
        assert_eq!(s.poly_order, 3);
        assert_eq!(s.order_of("y"), 5);
        assert_eq!(s.order_of("x"), 3);
        assert!(s.temps && s.temp_x_position && s.direction && !s.aux);
        assert_eq!(s.cross_order, 2);
        assert_eq!(
            DesignSpec::parse("static").unwrap(),
            DesignSpec::published_static()
        );
        assert!(DesignSpec::parse("poly=x").is_err());
        assert!(DesignSpec::parse("cubic").is_err());
    }

    #[test]
    fn eq22_is_pure_powers_of_each_axis_without_products() {
        assert_eq!(
            DesignSpec::parse("eq22").unwrap(),
            DesignSpec::published_2dof()
        );
        assert_eq!(
            DesignSpec::parse("poly=3 other_poly=3 temps").unwrap(),
            DesignSpec::published_2dof()
        );
        let d = two_axis_dwells();
        let spec = DesignSpec::published_2dof();
        let frame = DesignFrame::from_dwells(&d, &spec).unwrap();
        // q_x = a1x x + a2x x² + a3x x³ + b1x y + b2x y² + b3x y³ + c1x t1 + c2x t2 (+ λ_x)
        let names = |o| -> Vec<String> {
            frame
                .candidates(&spec, o)
                .into_iter()
                .map(|c| c.name)
                .collect()
        };
        assert_eq!(
            names(0),
            ["x", "x^2", "x^3", "y", "y^2", "y^3", "temp_a", "temp_b"]
        );
        assert_eq!(
            names(1),
            ["y", "y^2", "y^3", "x", "x^2", "x^3", "temp_a", "temp_b"]
        );
        // `cross` adds the products on top, each monomial once
        let both = DesignSpec::parse("eq22 cross=2").unwrap();
        assert_eq!(
            frame.candidates(&both, 0).len(),
            8 + 1,
            "x*y is the only new monomial of degree ≤ 2"
        );
    }

    fn two_axis_dwells() -> Dwells {
        let n = 20;
        let v = |f: fn(usize) -> f64| (0..n).map(f).collect::<Vec<f64>>();
        Dwells {
            axes: vec!["x".into(), "y".into()],
            t_end_s: v(|i| i as f64),
            t_start_s: v(|i| i as f64),
            cmd_um: vec![v(|i| (i % 5) as f64), v(|i| (i / 5) as f64)],
            meas_um: vec![v(|i| (i % 5) as f64), v(|i| (i / 5) as f64)],
            meas_sd_um: vec![vec![0.0; n]; 2],
            dir: vec![vec![1; n]; 2],
            channels: vec![
                ("temp_a".into(), v(|i| 20.0 + 0.1 * i as f64)),
                ("temp_b".into(), v(|i| 21.0 - 0.05 * i as f64)),
            ],
            rows_averaged: vec![1; n],
        }
    }

    #[test]
    fn monomials_of_two_axes() {
        let m = monomials(2, 2);
        assert_eq!(m, vec![[2, 0, 0], [1, 1, 0], [0, 2, 0]]);
    }
}
