//! Building a model: in scaled terms (what a fit produces) or in raw units (what papers publish).

use crate::error::ModelError;
use crate::hysteresis::PlaySpec;
use crate::input::{AuxSpec, Input, Range, Scaling};
use crate::lag::LagSpec;
use crate::limits::{
    MAX_AUX, MAX_AXES, MAX_INPUTS, MAX_LAGS, MAX_PLAY, MAX_POWER, MAX_TEMPS, MAX_TERMS,
};
use crate::model::{powi, Model};
use crate::term::{Factor, Term};

/// Assembles a [`Model`]; terms of the same shape are merged by adding their coefficients.
#[derive(Clone, Debug)]
pub struct ModelBuilder {
    model: Model,
}

impl ModelBuilder {
    /// An empty model with the given numbers of axes, temperature and aux inputs; identity
    /// scalings, unbounded envelope and travel, aux inputs of kind "other" and slow.
    pub fn new(axes: usize, temps: usize, aux: usize) -> Result<Self, ModelError> {
        if axes == 0 {
            return Err(ModelError::NoAxes);
        }
        if axes > MAX_AXES || temps > MAX_TEMPS || aux > MAX_AUX {
            return Err(ModelError::TooManyInputs);
        }
        Ok(ModelBuilder {
            model: Model {
                id: 0,
                axes: axes as u8,
                temps: temps as u8,
                aux: aux as u8,
                lags: 0,
                plays: 0,
                aux_specs: [AuxSpec::default(); MAX_AUX],
                scaling: [Scaling::IDENTITY; MAX_INPUTS],
                envelope: [Range::UNBOUNDED; MAX_INPUTS],
                travel_um: [Range::UNBOUNDED; MAX_AXES],
                offset_um: [0.0; MAX_AXES],
                kmz_offset_um: [0.0; MAX_AXES],
                lag_specs: [LagSpec {
                    sensor: 0,
                    tau_s: 1.0,
                }; MAX_LAGS],
                play_specs: [PlaySpec {
                    axis: 0,
                    threshold_um: 0.0,
                }; MAX_PLAY],
                terms: [Term {
                    output: 0,
                    powers: [0; MAX_AXES],
                    factor: Factor::None,
                    direction: 0,
                    coeff: 0.0,
                }; MAX_TERMS],
                n_terms: 0,
                bounds: [None; MAX_AXES],
                provenance: crate::provenance::Provenance::UNKNOWN,
            },
        })
    }

    /// A builder that starts from an existing model, to extend it (e.g. with a play-operator
    /// bank or another aux input).
    pub fn from_model(model: &Model) -> Self {
        ModelBuilder {
            model: model.clone(),
        }
    }

    /// Adds an aux input (after the existing ones) with identity scaling and an unbounded
    /// envelope; returns its index for [`Factor::Aux`].
    pub fn add_aux(&mut self, spec: AuxSpec) -> Result<u8, ModelError> {
        let n = self.model.aux;
        if n as usize >= MAX_AUX {
            return Err(ModelError::TooManyInputs);
        }
        self.model.aux += 1;
        self.model.aux_specs[n as usize] = spec;
        Ok(n)
    }

    /// Sets the model's identifier.
    pub fn id(mut self, id: u32) -> Self {
        self.model.id = id;
        self
    }

    /// Sets the scaling of an input. Set scalings before adding raw terms: raw terms are
    /// expanded with the scalings in force when they are added.
    pub fn scaling(mut self, input: Input, scaling: Scaling) -> Self {
        self.model.scaling[input.flat_index().min(MAX_INPUTS - 1)] = scaling;
        self
    }

    /// Sets the training envelope of an input.
    pub fn envelope(mut self, input: Input, min: f64, max: f64) -> Self {
        self.model.envelope[input.flat_index().min(MAX_INPUTS - 1)] = Range { min, max };
        self
    }

    /// Sets the scaling *and* envelope of an input from its training range.
    pub fn trained_range(self, input: Input, min: f64, max: f64) -> Self {
        self.scaling(input, Scaling::from_range(min, max))
            .envelope(input, min, max)
    }

    /// Declares what aux input `n` measures and whether it is fast (evaluated per command) or
    /// slow (folded). Ignored for an aux input the model does not have.
    pub fn aux_spec(mut self, n: usize, spec: AuxSpec) -> Self {
        if n < self.model.aux() {
            self.model.aux_specs[n] = spec;
        }
        self
    }

    /// Sets the stage travel of an axis in command space, µm.
    pub fn travel_um(mut self, axis: usize, min: f64, max: f64) -> Self {
        self.model.travel_um[axis.min(MAX_AXES - 1)] = Range { min, max };
        self
    }

    /// Adds to the static offset λ of an axis, µm.
    pub fn offset_um(mut self, axis: usize, value_um: f64) -> Self {
        self.model.offset_um[axis.min(MAX_AXES - 1)] += value_um;
        self
    }

    /// Sets the adaptive offset λ_KMZ of an axis, µm.
    pub fn kmz_offset_um(mut self, axis: usize, value_um: f64) -> Self {
        self.model.kmz_offset_um[axis.min(MAX_AXES - 1)] = value_um;
        self
    }

    /// Declares a lag filter on a temperature sensor; returns its index for [`Factor::Lagged`].
    pub fn lag(&mut self, sensor: u8, tau_s: f64) -> Result<u8, ModelError> {
        let k = self.model.lags;
        if k as usize >= MAX_LAGS {
            return Err(ModelError::TooManyInputs);
        }
        if sensor >= self.model.temps || !(tau_s > 0.0 && tau_s.is_finite()) {
            return Err(ModelError::InvalidLag { lag: k });
        }
        self.model.lag_specs[k as usize] = LagSpec { sensor, tau_s };
        self.model.lags += 1;
        Ok(k)
    }

    /// Declares a play operator (hysteresis) fed by the target of `axis`, with threshold
    /// `threshold_um`; returns its index for [`Factor::Play`]. Declare each axis' operators
    /// together, axes in order, thresholds strictly ascending (see [`crate::hysteresis`]).
    pub fn play(&mut self, axis: u8, threshold_um: f64) -> Result<u8, ModelError> {
        let k = self.model.plays;
        if k as usize >= MAX_PLAY {
            return Err(ModelError::TooManyInputs);
        }
        self.model.play_specs[k as usize] = PlaySpec { axis, threshold_um };
        self.model.plays += 1;
        if let Err(e) = self.model.validate_play_operators() {
            self.model.plays -= 1;
            return Err(e);
        }
        Ok(k)
    }

    /// Declares the play-operator bank of `axis` in raw units: for each `(threshold_um,
    /// weight)`, an operator and the term `weight · y` on the axis' own command (`weight` is
    /// dimensionless, µm of command per µm of operator output). Set the axis' scaling first.
    pub fn play_bank(&mut self, axis: u8, bank: &[(f64, f64)]) -> Result<(), ModelError> {
        for &(threshold_um, weight) in bank {
            let k = self.play(axis, threshold_um)?;
            self.add_raw_term(axis, [0; MAX_AXES], Factor::Play(k), 0, weight)?;
        }
        Ok(())
    }

    /// Adds a term on scaled inputs. A term with no powers, factor or direction is a constant
    /// and goes into the offset λ.
    pub fn add_term(&mut self, term: Term) -> Result<(), ModelError> {
        let index = self.model.n_terms;
        self.model.validate_term(&term, index)?;
        if term.degree() == 0 && term.factor == Factor::None && term.direction == 0 {
            self.model.offset_um[term.output as usize] += term.coeff;
            return Ok(());
        }
        let n = self.model.n_terms as usize;
        if let Some(existing) = self.model.terms[..n]
            .iter_mut()
            .find(|t| t.same_shape(&term))
        {
            existing.coeff += term.coeff;
            return Ok(());
        }
        if n >= MAX_TERMS {
            return Err(ModelError::TooManyTerms);
        }
        self.model.terms[n] = term;
        self.model.n_terms += 1;
        Ok(())
    }

    /// Adds a term published in raw units: `coeff · Π_a x_a^powers[a] · factor · sign`, with
    /// positions in µm and the factor in its own unit. It is expanded into scaled terms with
    /// the binomial theorem (`x = c + s·u`), using the scalings set so far.
    pub fn add_raw_term(
        &mut self,
        output: u8,
        powers: [u8; MAX_AXES],
        factor: Factor,
        direction: u8,
        coeff: f64,
    ) -> Result<(), ModelError> {
        let shape = Term {
            output,
            powers,
            factor,
            direction,
            coeff,
        };
        self.model.validate_term(&shape, self.model.n_terms)?;
        // A raw factor v = c + s·w splits into c (no factor) and s·w (the scaled factor).
        let factor_parts: [(Factor, f64); 2] = match factor {
            Factor::None => [(Factor::None, 1.0), (Factor::None, 0.0)],
            f => {
                let sc = self.model.scaling(self.factor_input(f));
                [(Factor::None, sc.centre), (f, sc.half_range)]
            }
        };
        let [p0, p1, p2] = powers;
        for k0 in 0..=p0 {
            for k1 in 0..=p1 {
                for k2 in 0..=p2 {
                    let ks = [k0, k1, k2];
                    let mut c = coeff;
                    for a in 0..MAX_AXES {
                        let sc = self.model.scaling[a];
                        let p = powers[a];
                        c *= binomial(p, ks[a])
                            * powi(sc.centre, p - ks[a])
                            * powi(sc.half_range, ks[a]);
                    }
                    for &(f, weight) in &factor_parts {
                        if weight != 0.0 {
                            let term = Term {
                                output,
                                powers: ks,
                                factor: f,
                                direction,
                                coeff: c * weight,
                            };
                            self.add_term(term)?;
                        }
                    }
                }
            }
        }
        Ok(())
    }

    fn factor_input(&self, factor: Factor) -> Input {
        match factor {
            Factor::Temp(n) => Input::Temp(n),
            Factor::Aux(n) => Input::Aux(n),
            Factor::Lagged(k) => Input::Temp(self.model.lag_specs[k as usize].sensor),
            Factor::Play(k) => Input::Axis(self.model.play_specs[k as usize].axis),
            Factor::None => Input::Axis(0),
        }
    }

    /// The model as it stands, unchecked: the blob decoder fills in the rest, then validates.
    pub(crate) fn into_unchecked(self) -> Model {
        self.model
    }

    /// Checks the whole model and returns it.
    pub fn build(self) -> Result<Model, ModelError> {
        self.model.validate()?;
        Ok(self.model)
    }
}

/// Binomial coefficient C(n, k) as f64 (n ≤ `MAX_POWER`).
fn binomial(n: u8, k: u8) -> f64 {
    debug_assert!(n <= MAX_POWER);
    let mut c = 1.0;
    for i in 0..k {
        c = c * (n - i) as f64 / (i + 1) as f64;
    }
    c
}
