//! What explain found: per channel and for the whole recording, as text and as JSON.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde::Serialize;

use super::data::Data;
use super::locate::{Finding, NoiseFloor};
use super::Trial;
use crate::effects::Estimate;

/// A named effect with its parameters and evidence.
#[derive(Clone, Debug)]
pub struct EffectReport {
    /// One of the nine names.
    pub name: &'static str,
    /// The channel it was found on.
    pub channel: String,
    /// Plain-words description.
    pub description: &'static str,
    /// Where the compensator can run it.
    pub deploy: &'static str,
    /// The shared-model terms (and lag filters) that carry it into the blob, if deployable.
    pub blob: Option<crate::effects::BlobTerms>,
    /// Physical parameters with 1σ.
    pub params: Vec<Estimate>,
    /// Held-out RMS before adding the effect, nm.
    pub rms_before_nm: f64,
    /// Held-out RMS after, nm.
    pub rms_after_nm: f64,
    /// The evidence in words and numbers.
    pub evidence: String,
}

/// ISO 9283-style positioning accuracy over poses (1-D: |mean deviation| per pose and direction).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IsoAccuracy {
    /// Largest accuracy over poses, nm.
    pub max_accuracy_nm: f64,
    /// Largest repeatability (mean |x − x̄| + 3σ) over poses, nm.
    pub max_repeatability_nm: f64,
    /// Number of (pose, direction) groups.
    pub poses: usize,
}

/// What explain found on one channel.
#[derive(Clone, Debug)]
pub struct ChannelReport {
    /// Channel name.
    pub channel: String,
    /// What the baseline is.
    pub baseline: String,
    /// Rows.
    pub rows: usize,
    /// Noise floor of the baseline residual.
    pub noise_floor: NoiseFloor,
    /// Held-out RMS of the baseline, nm.
    pub baseline_rms_nm: f64,
    /// In-sample RMS of the baseline, nm.
    pub baseline_in_sample_rms_nm: f64,
    /// Held-out RMS of the final model, nm.
    pub final_rms_nm: f64,
    /// Where the baseline residual is structured.
    pub located: Vec<Finding>,
    /// Named effects, in the order they joined the model.
    pub effects: Vec<EffectReport>,
    /// Structure that remains unexplained.
    pub unexplained: Vec<Finding>,
    /// All candidates tried, per round.
    pub trials: Vec<Vec<Trial>>,
    /// Held-out residual of the baseline, µm.
    pub residual_before_um: Vec<f64>,
    /// Held-out residual of the final model, µm.
    pub residual_after_um: Vec<f64>,
    /// ISO accuracy of the baseline (held-out), when the axis was commanded.
    pub iso_before: Option<IsoAccuracy>,
    /// ISO accuracy of the final model (held-out).
    pub iso_after: Option<IsoAccuracy>,
}

/// What explain found on a recording.
#[derive(Clone, Debug)]
pub struct Report {
    /// One report per measured channel.
    pub channels: Vec<ChannelReport>,
}

/// JSON form of a named effect.
#[derive(Serialize, Debug, Clone)]
pub struct JsonEffect {
    /// Effect name.
    pub name: String,
    /// Channel (axis) it was found on.
    pub axis: String,
    /// Parameters; each `x` has its 1σ as `x_sigma` when known.
    pub params: BTreeMap<String, f64>,
    /// Held-out RMS before, nm.
    pub rms_before_nm: f64,
    /// Held-out RMS after, nm.
    pub rms_after_nm: f64,
    /// Evidence in words.
    pub evidence: String,
}

/// JSON form of an unexplained finding.
#[derive(Serialize, Debug, Clone)]
pub struct JsonUnexplained {
    /// Where (channel and place).
    #[serde(rename = "where")]
    pub place: String,
    /// RMS of the residual there, nm.
    pub rms_nm: f64,
}

/// The JSON document `nanocal explain --json` writes.
#[derive(Serialize, Debug, Clone)]
pub struct JsonReport {
    /// Held-out RMS of the baseline over all channels, nm.
    pub baseline_rms_nm: f64,
    /// Named effects (empty: nothing significant is missing).
    pub effects: Vec<JsonEffect>,
    /// Structure no candidate explains.
    pub unexplained: Vec<JsonUnexplained>,
}

/// ISO 9283 accuracy and repeatability (host's [`crate::iso9283`]) of a held-out residual `r`
/// (µm) on a commanded channel: one visit per dwell (its mean), poses split by direction of
/// approach (forward and backward are different poses, as the literature reports them).
pub fn iso_accuracy(d: &Data, ch: usize, r: &[f64]) -> Option<IsoAccuracy> {
    let c = &d.channels[ch];
    let cmd = c.cmd_um.as_ref()?;
    c.u.as_ref()?;
    let mut bounds = vec![0usize];
    bounds.extend(c.steps.iter().map(|s| s.0));
    bounds.push(d.rows());
    let (mut targets, mut errors) = (Vec::new(), Vec::new());
    for w in bounds.windows(2) {
        let (a, b) = (w[0], w[1]);
        let vals: Vec<f64> = r[a..b.max(a)]
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .collect();
        if vals.is_empty() {
            continue;
        }
        let dir = c.dir.as_ref().map_or(0.0, |dv| dv[a]);
        targets.push(vec![cmd[a], dir]);
        errors.push(vec![vals.iter().sum::<f64>() / vals.len() as f64, 0.0]);
    }
    // the direction rides along as a second coordinate (error 0) only to split the groups
    let poses = crate::iso9283::per_pose(&targets, &errors);
    let (acc, rep) = crate::iso9283::max_over_poses(&poses);
    Some(IsoAccuracy {
        max_accuracy_nm: acc * 1e3,
        max_repeatability_nm: rep * 1e3,
        poses: poses.len(),
    })
}

impl Report {
    /// Held-out baseline RMS over all channels, nm.
    pub fn baseline_rms_nm(&self) -> f64 {
        let n = self.channels.len().max(1) as f64;
        (self
            .channels
            .iter()
            .map(|c| c.baseline_rms_nm.powi(2))
            .sum::<f64>()
            / n)
            .sqrt()
    }

    /// All named effects over all channels.
    pub fn effects(&self) -> impl Iterator<Item = &EffectReport> {
        self.channels.iter().flat_map(|c| c.effects.iter())
    }

    /// The JSON document.
    pub fn to_json(&self) -> JsonReport {
        let effects = self
            .effects()
            .map(|e| {
                let mut params = BTreeMap::new();
                for p in &e.params {
                    params.insert(p.name.clone(), finite(p.value));
                    if p.sigma.is_finite() && p.sigma > 0.0 {
                        params.insert(format!("{}_sigma", p.name), p.sigma);
                    }
                }
                JsonEffect {
                    name: e.name.to_string(),
                    axis: e.channel.clone(),
                    params,
                    rms_before_nm: finite(e.rms_before_nm),
                    rms_after_nm: finite(e.rms_after_nm),
                    evidence: e.evidence.clone(),
                }
            })
            .collect();
        let unexplained = self
            .channels
            .iter()
            .flat_map(|c| {
                c.unexplained.iter().map(move |f| JsonUnexplained {
                    place: format!(
                        "{}: {} ({}, mean {:+.1} nm)",
                        c.channel, f.place, f.dimension, f.mean_nm
                    ),
                    rms_nm: finite(f.rms_nm),
                })
            })
            .collect();
        JsonReport {
            baseline_rms_nm: finite(self.baseline_rms_nm()),
            effects,
            unexplained,
        }
    }

    /// The report for a person.
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        for c in &self.channels {
            let _ = writeln!(s, "── channel {} ({} rows)", c.channel, c.rows);
            let _ = writeln!(s, "  baseline: {}", c.baseline);
            let _ = writeln!(
                s,
                "  noise floor from the data: {:.1} nm sample-to-sample, {:.1} nm per independent unit",
                c.noise_floor.sample_um * 1e3,
                c.noise_floor.unit_um * 1e3
            );
            let _ = writeln!(
                s,
                "  baseline RMS: {:.1} nm held-out ({:.1} nm in-sample)",
                c.baseline_rms_nm, c.baseline_in_sample_rms_nm
            );
            if c.located.is_empty() {
                let _ = writeln!(s, "  locate: no structure above the noise floor");
            } else {
                let _ = writeln!(s, "  locate: structured residual");
                for f in c.located.iter().take(10) {
                    let _ = writeln!(
                        s,
                        "    - {} [{}]: mean {:+.1} nm, RMS {:.1} nm ({:.0}σ)",
                        f.place, f.dimension, f.mean_nm, f.rms_nm, f.z
                    );
                }
            }
            if c.effects.is_empty() {
                let _ = writeln!(s, "  name: nothing significant is missing");
            }
            for e in &c.effects {
                let _ = writeln!(s, "  name: {} — {}", e.name, e.description);
                let ps: Vec<String> = e
                    .params
                    .iter()
                    .map(|p| {
                        if p.sigma.is_finite() && p.sigma > 0.0 {
                            format!("{} = {} ± {}", p.name, sig(p.value), sig(p.sigma))
                        } else {
                            format!("{} = {}", p.name, sig(p.value))
                        }
                    })
                    .collect();
                let _ = writeln!(s, "    parameters: {}", ps.join(", "));
                let _ = writeln!(s, "    evidence: {}", e.evidence);
                let _ = writeln!(s, "    compensator: {}", e.deploy);
                if let Some(b) = &e.blob {
                    let _ = writeln!(
                        s,
                        "    blob: {} term shape(s), {} lag filter(s) to fit into the shared model",
                        b.terms.len(),
                        b.lags.len()
                    );
                }
            }
            if let Some(last) = c.trials.last() {
                let rejected: Vec<String> = last
                    .iter()
                    .filter(|t| !t.passed)
                    .map(|t| {
                        if t.cv_rms_um.is_finite() {
                            format!(
                                "{} (ΔBIC {:.0}, held-out {:.1} nm, {}/5 folds)",
                                t.name,
                                t.delta_bic,
                                t.cv_rms_um * 1e3,
                                t.folds_better
                            )
                        } else {
                            format!("{} (ΔBIC {:+.0})", t.name, t.delta_bic)
                        }
                    })
                    .collect();
                if !rejected.is_empty() {
                    let _ = writeln!(s, "  not supported by the data: {}", rejected.join("; "));
                }
            }
            let _ = writeln!(
                s,
                "  RMS held-out: before {:.1} nm → after {:.1} nm",
                c.baseline_rms_nm, c.final_rms_nm
            );
            if let (Some(b), Some(a)) = (c.iso_before, c.iso_after) {
                let _ = writeln!(
                    s,
                    "  ISO 9283 (held-out, {} pose/direction groups): accuracy {:.1} → {:.1} nm, repeatability {:.1} → {:.1} nm",
                    b.poses, b.max_accuracy_nm, a.max_accuracy_nm, b.max_repeatability_nm, a.max_repeatability_nm
                );
            }
            if c.unexplained.is_empty() {
                let _ = writeln!(s, "  unexplained: nothing above the noise floor");
            } else {
                let _ = writeln!(s, "  unexplained (no candidate explains it):");
                for f in &c.unexplained {
                    let _ = writeln!(
                        s,
                        "    - {} [{}]: RMS {:.1} nm, mean {:+.1} nm",
                        f.place, f.dimension, f.rms_nm, f.mean_nm
                    );
                }
            }
        }
        s
    }
}

fn finite(v: f64) -> f64 {
    if v.is_finite() {
        v
    } else {
        0.0
    }
}

fn sig(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let mag = v.abs().log10().floor() as i32;
    let dec = (2 - mag).clamp(0, 9) as usize;
    format!("{v:.dec$}")
}
