//! The validate-and-return loop of paper 001 §II, step 5: "Validation (evaluation of the robot
//! absolute accuracy) and eventually return to 1. (if the desired absolute accuracy has not yet
//! been reached and consider other sources of inaccuracy), or return to 0. (if all the possible
//! sources of inaccuracy have already been considered)".
//!
//! After a validation (the plan's, then each loop's block), with a desired accuracy `A`
//! (`--target-accuracy-nm`; the worst static test's Acc, Eq. 6):
//! 1. **Met**: the static model's worst test is within `A` — stop.
//! 2. **Held-out evidence** (from the second validation on): the loop's model and the one
//!    before it, evaluated on the same block's data — never used for a fit — open loop (the
//!    target for which each model sends the recorded command, [`crate::validate`]); a loop that
//!    does not improve the mean test accuracy of the block (the numerator of paper 000's time
//!    robustness, Eq. 21: one test's bad hour does not decide) stops the loop, and its model
//!    is not kept.
//! 3. **Step 1, more sources of inaccuracy**: `explain` on the validation's steps; every
//!    effect it names that deploys in the blob (lag filters, play operators, interactions,
//!    temperature terms) and that the model does not carry yet joins the candidates; the static
//!    model is fitted again on the training data (stepwise, as paper 000 §3.3) and a block of
//!    validation tests with it follows, through the compensator.
//! 4. **Step 0, the design**: explain names nothing the blob can carry — what remains needs a
//!    sensor where a source is, or is a source with no input — stop and say which.
//!
//! Every decision is in the campaign's state: a stopped campaign resumes where it was.

use super::analysis::{explain_report, recording_from, two_tables};
use super::run::{static_blob, CampaignError, Models, MODEL_IDS};
use super::state::{LoopRecord, LoopState, LoopStop, State};
use crate::data::plan::{Phase, Plan, Step, TestKind};
use crate::data::recording::Recording;
use crate::device::device_path::SlowPeriods;
use crate::fit::design::{DesignSpec, Extension};
use crate::fit::{encode_blob, fit_dwells, parameter_count, FitOptions, Selection};
use crate::validate::procedure::ProcedureData;
use nanocal_model::Model;
use std::path::Path;

/// What the loop decided after a validation.
#[derive(Debug, Clone, PartialEq)]
pub enum Decision {
    /// A loop started: its block of validation tests follows (the schedule with it).
    Block(Vec<Step>),
    /// The loop stopped (why is in the state).
    Stop,
}

fn err(e: impl std::fmt::Display) -> CampaignError {
    CampaignError::Fit(e.to_string())
}

/// Id of the static model of loop `l` (0: the plan's).
pub fn model_id(l: usize) -> u32 {
    MODEL_IDS.0 + 0x100 * l as u32
}

/// The steps of validation `v` (0: the plan's validation; `l`: loop `l`'s block) in `steps`.
fn validation_steps(plan: &Plan, steps: &[Step], v: usize, tests_per_block: usize) -> Vec<Step> {
    let tests = plan.tests();
    steps
        .iter()
        .filter(|s| {
            let test = match s.phase {
                Phase::Training => return false,
                Phase::Kmz { test, .. } | Phase::Test { test, .. } => test,
            };
            match v {
                0 => test < tests,
                l => {
                    (tests + (l - 1) * tests_per_block..tests + l * tests_per_block).contains(&test)
                }
            }
        })
        .cloned()
        .collect()
}

fn read_model(dir: &Path, name: &str) -> Result<Model, CampaignError> {
    let b = std::fs::read(dir.join(name)).map_err(|e| err(format!("{name}: {e}")))?;
    nanocal_model::blob::decode(&b).map_err(|e| err(format!("{name}: {e}")))
}

/// The static model of loop `l` (0: the plan's, before any loop refitted it).
fn static_model(dir: &Path, l: usize) -> Result<Model, CampaignError> {
    if l == 0 && !dir.join(static_blob(0)).exists() {
        return Models::load(dir).map(|m| m.static_model);
    }
    read_model(dir, &static_blob(l))
}

/// The mean and worst test accuracy of a validation.
fn block_accuracy(r: &crate::validate::ValidationReport) -> super::state::BlockAccuracy {
    let n = r.tests.len().max(1) as f64;
    super::state::BlockAccuracy {
        mean_nm: r.tests.iter().map(|t| t.accuracy_um).sum::<f64>() / n * 1e3,
        worst_nm: worst_nm(r),
    }
}

/// Worst test Acc of a validation, nm.
fn worst_nm(r: &crate::validate::ValidationReport) -> f64 {
    r.summary.max_acc_um * 1e3
}

/// Decide after validation `v` (0: the plan's, `l`: loop `l`'s block), the steps so far being
/// `steps` (see the module doc). Writes the models a new loop needs and records everything
/// in `state`; the caller saves it.
pub fn decide(
    dir: &Path,
    plan: &Plan,
    steps: &[Step],
    base: &DesignSpec,
    periods: SlowPeriods,
    state: &mut State,
) -> Result<Decision, CampaignError> {
    let Some(lp) = state.loops.clone() else {
        return Ok(Decision::Stop);
    };
    let v = lp.decided;
    let rec = Recording::read_path(dir.join(super::RECORDING)).map_err(err)?;
    let vsteps = validation_steps(plan, steps, v, lp.tests_per_block);
    // a refitted model primes its lag filters at its upload: replay from the block's start
    let rec_v = match (v, vsteps.first()) {
        (1.., Some(first)) => recording_from(&rec, first.t_start_s)?,
        _ => rec.clone(),
    };
    let data = ProcedureData::new(&rec_v, &vsteps, 0.0).map_err(err)?;
    let model = static_model(dir, v)?;
    let replay: SlowPeriods = if model.lags().is_empty() {
        1.0.into()
    } else {
        periods.fold_s.into()
    };
    let (through, file) = two_tables(&data, plan, TestKind::Static, Some(&model), replay)?;
    let acc_nm = worst_nm(&through);
    let mut lp = lp;
    lp.decided = v + 1;
    let decision = (|| -> Result<Decision, CampaignError> {
        if v >= 1 {
            // held-out evidence: the model before this loop on the same block, open loop
            let before = static_model(dir, v - 1)?;
            let r = data
                .validate(TestKind::Static, Some(&before), None, replay)
                .map_err(err)?;
            let (b, a) = (block_accuracy(&r), block_accuracy(&through));
            let rec_l = &mut lp.loops[v - 1];
            rec_l.before = Some(b);
            rec_l.after = Some(a);
            rec_l.agreement_nm = Some(super::analysis::difference_nm(&through, &file));
            let outside = (through.outside_envelope, through.distribution.n);
            rec_l.outside_training = Some(outside);
            if a.mean_nm >= b.mean_nm {
                // not kept: the compensator gets the model before it back at the next upload
                std::fs::copy(dir.join(static_blob(v - 1)), dir.join("static.blob"))
                    .map_err(err)?;
                state.model_ids = state.model_ids.map(|(_, a)| (model_id(v - 1), a));
                let mut advice = Vec::new();
                if outside.0 * 10 > outside.1 {
                    advice.push(format!(
                        "{} of the block's {} visits had temperatures outside the training range: a model fitted on the training cannot be checked there — train over the range of use (paper 001 §IV.C: \"vary the temperatures acting on the robot in the same range of temperatures that the robot will encounter during its normal use\")",
                        outside.0, outside.1
                    ));
                }
                lp.stop = Some(LoopStop::NoImprovement {
                    before_nm: b.mean_nm,
                    after_nm: a.mean_nm,
                    advice,
                });
                return Ok(Decision::Stop);
            }
        }
        if acc_nm <= lp.target_nm {
            lp.stop = Some(LoopStop::TargetMet { acc_nm });
            return Ok(Decision::Stop);
        }
        if lp.loops.len() >= lp.max_loops {
            lp.stop = Some(LoopStop::MaxLoops);
            return Ok(Decision::Stop);
        }
        // step 1: what explain names that the blob carries and the model does not yet
        let report = explain_report(&data).map_err(err)?;
        let carried: Vec<&str> = lp
            .loops
            .iter()
            .flat_map(|l| l.added.iter().map(|e| e.name.as_str()))
            .collect();
        let mut added = Vec::new();
        let mut evidence = Vec::new();
        let mut design = Vec::new();
        if let Some(report) = &report {
            for e in report.effects() {
                let name = format!("{} on {}", e.name, e.channel);
                match &e.blob {
                    Some(b) if !carried.contains(&name.as_str()) => {
                        added.push(Extension::from_blob_terms(&name, b));
                        evidence.push(format!(
                            "{name}: {} (held-out RMS {:.1} → {:.1} nm; {})",
                            e.summary, e.rms_before_nm, e.rms_after_nm, e.evidence
                        ));
                    }
                    Some(_) => {}
                    None => design.push(format!("{name}: {}", e.deploy)),
                }
            }
            for ch in &report.channels {
                for f in &ch.unexplained {
                    design.push(format!(
                        "on {}: structure no candidate explains {} ({:.0} nm RMS, {:.0}σ) — a source with no input the model can read: a sensor where it comes from",
                        ch.channel, f.place, f.rms_nm, f.z
                    ));
                }
            }
        }
        if added.is_empty() {
            if design.is_empty() {
                design.push(format!(
                    "explain finds nothing left above the noise floor: {acc_nm:.0} nm is what this stage, its sensors and the reference instrument allow — better sensors, a stiffer or better-shielded design (step 0)"
                ));
            }
            lp.stop = Some(LoopStop::DesignChange { advice: design });
            return Ok(Decision::Stop);
        }
        // back to step 1: the static model with the new sources of inaccuracy, on training data
        let l = lp.loops.len() + 1;
        if l == 1 {
            std::fs::copy(dir.join("static.blob"), dir.join(static_blob(0))).map_err(err)?;
        }
        let mut spec = base.clone();
        for r in &lp.loops {
            spec.extensions.extend(r.added.iter().cloned());
        }
        spec.extensions.extend(added.iter().cloned());
        let training: Vec<Step> = steps
            .iter()
            .filter(|s| s.phase == Phase::Training)
            .cloned()
            .collect();
        let tdata = ProcedureData::new(&rec, &training, 0.0).map_err(err)?;
        let fit = fit_dwells(
            &tdata.training(),
            &FitOptions {
                spec,
                selection: Selection::Stepwise(
                    crate::numerics::stepwise::StepwiseOptions::default(),
                ),
                dwell: Default::default(),
                id: model_id(l),
            },
        )
        .map_err(err)?;
        let blob = encode_blob(&fit.model);
        std::fs::write(dir.join(static_blob(l)), &blob).map_err(err)?;
        std::fs::write(dir.join("static.blob"), &blob).map_err(err)?;
        let n = parameter_count(&fit);
        lp.loops.push(LoopRecord {
            added,
            evidence,
            model_id: fit.model.id(),
            parameters: (n.geometric, n.thermal, n.other),
            acc_from_nm: acc_nm,
            before: None,
            after: None,
            agreement_nm: None,
            outside_training: None,
        });
        Ok(Decision::Block(
            plan.schedule_with_blocks(lp.loops.len(), lp.tests_per_block),
        ))
    })();
    let decision = decision?;
    if let Decision::Block(_) = decision {
        state.model_ids = state.model_ids.map(|(_, a)| (model_id(lp.loops.len()), a));
    }
    state.loops = Some(lp);
    Ok(decision)
}

/// The loop's schedule: the plan's, then the blocks of the loops started.
pub fn schedule(plan: &Plan, loops: Option<&LoopState>) -> Vec<Step> {
    match loops {
        Some(lp) => plan.schedule_with_blocks(lp.loops.len(), lp.tests_per_block),
        None => plan.schedule(),
    }
}
