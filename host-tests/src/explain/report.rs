//! What explain found: per channel and for the whole recording, as text and as JSON.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde::Serialize;

use super::contract::PlayOperator;
use super::data::Data;
use super::estimate::Estimate;
use super::faults::DataFault;
use super::locate::{Finding, NoiseFloor};
use super::robust::rows_in_words;
use super::units::{duration, length_um, sig3, TimeUnit};
use super::Trial;

/// A named effect with its parameters and evidence.
#[derive(Clone, Debug)]
pub struct EffectReport {
    /// One of the nine names.
    pub name: &'static str,
    /// The channel it was found on.
    pub channel: String,
    /// Plain-words description.
    pub description: &'static str,
    /// What was found, in words (which sensor lags how, the sense of a loop), or empty.
    pub summary: String,
    /// Where the compensator can run it.
    pub deploy: &'static str,
    /// The shared-model terms (and lag filters, play operators) that carry it into the blob,
    /// if deployable.
    pub blob: Option<super::contract::BlobTerms>,
    /// Physical parameters with 1σ.
    pub params: Vec<Estimate>,
    /// Held-out RMS before adding the effect, nm (standard held-out design).
    pub rms_before_nm: f64,
    /// Held-out RMS after, nm (standard held-out design).
    pub rms_after_nm: f64,
    /// The evidence in words and numbers.
    pub evidence: String,
}

impl EffectReport {
    /// A parameter by name.
    pub fn param(&self, name: &str) -> Option<&Estimate> {
        self.params.iter().find(|p| p.name == name)
    }
}

/// ISO 9283-style positioning accuracy over poses (1-D: |mean deviation| per pose and direction).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IsoAccuracy {
    /// Largest accuracy over poses, nm.
    pub max_accuracy_nm: f64,
    /// Largest repeatability (mean |x − x̄| + 3σ) over poses, nm.
    pub max_repeatability_nm: f64,
    /// Number of (pose, direction) groups visited at least twice.
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
    /// Quantisation step of the measurement, µm, if its readings sit on a grid.
    pub quant_step_um: Option<f64>,
    /// True when the measurement was held between slower updates.
    pub held: bool,
    /// Outlier rows (0-based), excluded from fitting.
    pub outliers: Vec<usize>,
    /// Largest excursion of an outlier, µm.
    pub outlier_max_um: f64,
    /// Rows (0-based) every model missed by far (a start-up transient, a reading taken while
    /// moving), excluded from the final pass.
    pub model_outliers: Vec<usize>,
    /// Held-out RMS of the baseline, nm.
    pub baseline_rms_nm: f64,
    /// In-sample RMS of the baseline, nm.
    pub baseline_in_sample_rms_nm: f64,
    /// Held-out RMS of the final model, nm.
    pub final_rms_nm: f64,
    /// Where the baseline residual is structured.
    pub located: Vec<Finding>,
    /// Events: steps of the residual (a slip, a re-seat, a collision), located and modelled
    /// as an offset from their row on before any effect was named.
    pub events: Vec<super::events::Event>,
    /// Structure a flexible alternative carries that no listed form explains (see
    /// [`super::misspec`]); also listed first among `unexplained`.
    pub not_in_library: Vec<super::misspec::Misfit>,
    /// Targeted tests for small effects (see [`super::targeted`]), significant or not.
    pub targeted: Vec<super::targeted::TargetedTest>,
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
    /// ISO accuracy of the baseline (held-out), when poses were revisited.
    pub iso_before: Option<IsoAccuracy>,
    /// ISO accuracy of the final model (held-out).
    pub iso_after: Option<IsoAccuracy>,
}

impl ChannelReport {
    /// One line that always says which of the two it is: nothing significant remains, or
    /// structure remains that no candidate explains (and the names found, if any).
    pub fn headline(&self) -> String {
        let named = if self.effects.is_empty() {
            "nothing named".to_string()
        } else {
            format!(
                "named {}",
                self.effects
                    .iter()
                    .map(|e| e.name)
                    .collect::<Vec<_>>()
                    .join(" + ")
            )
        };
        let events: String = self
            .events
            .iter()
            .map(|e| {
                format!(
                    "; event: a step of {} at data row {} (check the mount)",
                    length_um(e.size_um),
                    e.row + 1
                )
            })
            .collect();
        let named = format!("{named}{events}");
        if self.unexplained.is_empty() {
            format!("{named}; nothing significant remains (the held-out residual is at the noise floor)")
        } else {
            let top = &self.unexplained[0];
            if top.z.is_finite() {
                format!(
                    "{named}; structure remains that no candidate explains ({}, {:.0}σ)",
                    top.place, top.z
                )
            } else {
                format!(
                    "{named}; structure remains that no candidate explains: {}",
                    top.place
                )
            }
        }
    }
}

/// What explain found on a recording.
#[derive(Clone, Debug)]
pub struct Report {
    /// One report per measured channel.
    pub channels: Vec<ChannelReport>,
    /// The unit of time that fits the record.
    pub time_unit: TimeUnit,
    /// Duration of the record, s.
    pub duration_s: f64,
    /// Temperature glitches repaired (column, rows).
    pub temp_repairs: Vec<(String, Vec<usize>)>,
    /// Data faults (sensors or logging to check, not physics), found before any fitting.
    pub data_faults: Vec<DataFault>,
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
    /// What was found, in words.
    pub summary: String,
    /// Held-out RMS before, nm.
    pub rms_before_nm: f64,
    /// Held-out RMS after, nm.
    pub rms_after_nm: f64,
    /// Evidence in words.
    pub evidence: String,
    /// Play operators for the compensator's per-axis bank (hysteresis), if any.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub play_operators: Vec<PlayOperator>,
    /// Lag filters (sensor index, τ in s) the blob would declare (thermal lag), if any.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub lag_filters: Vec<(u8, f64)>,
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

/// JSON summary of one channel.
#[derive(Serialize, Debug, Clone)]
pub struct JsonChannel {
    /// Channel (axis).
    pub axis: String,
    /// The headline (nothing significant remains / structure remains that no candidate explains).
    pub headline: String,
    /// True when structure remains that no candidate explains.
    pub structure_remains: bool,
    /// Noise floor, nm (sample to sample).
    pub noise_floor_nm: f64,
    /// Quantisation step of the measurement, nm, when its readings sit on a grid.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub quantisation_nm: Option<f64>,
    /// Outlier rows (data rows counted from 1), excluded from fitting.
    pub outlier_rows: Vec<usize>,
    /// Held-out RMS before, nm.
    pub baseline_rms_nm: f64,
    /// Held-out RMS after, nm.
    pub final_rms_nm: f64,
    /// Events: steps of the residual located on the way (a slip, a re-seat: check the mount).
    pub events: Vec<JsonEvent>,
}

/// JSON form of an event (a step of the residual).
#[derive(Serialize, Debug, Clone)]
pub struct JsonEvent {
    /// First data row (counted from 1) at the new level.
    pub row: usize,
    /// Data rows (from 1) the step may lie between.
    pub row_range: [usize; 2],
    /// Time after the start, s.
    pub t_s: f64,
    /// Size of the step, nm.
    pub size_nm: f64,
    /// Its 1σ, nm.
    pub size_sigma_nm: f64,
}

/// The JSON document `nanocal explain --json` writes.
#[derive(Serialize, Debug, Clone)]
pub struct JsonReport {
    /// Held-out RMS of the baseline over all channels, nm.
    pub baseline_rms_nm: f64,
    /// Per channel: headline, noise floor, outliers.
    pub channels: Vec<JsonChannel>,
    /// Named effects (empty: nothing significant is missing).
    pub effects: Vec<JsonEffect>,
    /// Structure no candidate explains.
    pub unexplained: Vec<JsonUnexplained>,
    /// Data faults: sensors or logging to check, not physics.
    pub data_faults: Vec<JsonFault>,
    /// Structure that no listed form explains (a flexible alternative carries it).
    pub not_in_library: Vec<JsonMisfit>,
}

/// JSON form of structure no listed form explains.
#[derive(Serialize, Debug, Clone)]
pub struct JsonMisfit {
    /// Channel (axis).
    pub axis: String,
    /// The coordinate it lives in.
    pub coordinate: String,
    /// What it is.
    pub description: String,
    /// Held-out RMS it carries, nm.
    pub rms_nm: f64,
    /// Listed names withdrawn for it.
    pub withdrawn: Vec<String>,
    /// The numbers behind it.
    pub evidence: String,
}

/// JSON form of a data fault.
#[derive(Serialize, Debug, Clone)]
pub struct JsonFault {
    /// Kind (`frozen`, `clock_jump`, …).
    pub kind: super::faults::FaultKind,
    /// The column.
    pub column: String,
    /// Affected rows as [first, last] data rows counted from 1 (empty: the whole record).
    pub rows: Vec<[usize; 2]>,
    /// What was seen.
    pub detail: String,
    /// What explain did about it.
    pub handling: String,
    /// True for a sensor or logger to check; false for a property of the logging explain
    /// handles (sample-and-hold).
    pub needs_check: bool,
}

/// ISO 9283 accuracy and repeatability (host's [`crate::validate::iso9283`]) of a held-out residual `r`
/// (µm) on a commanded channel: one visit per dwell (its mean), poses split by direction of
/// approach (forward and backward are different poses, as the literature reports them). Only
/// where the procedure revisits poses: the command holds dwells and at least two
/// (pose, direction) groups are visited at least twice (a continuous drive has no poses).
pub fn iso_accuracy(d: &Data, ch: usize, r: &[f64]) -> Option<IsoAccuracy> {
    let c = &d.channels[ch];
    let cmd = c.cmd_um.as_ref()?;
    c.u.as_ref()?;
    if !c.has_dwells {
        return None;
    }
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
    let poses: Vec<_> = crate::validate::iso9283::per_pose(&targets, &errors)
        .into_iter()
        .filter(|p| p.n >= 2)
        .collect();
    if poses.len() < 2 {
        return None;
    }
    let (acc, rep) = crate::validate::iso9283::max_over_poses(&poses);
    Some(IsoAccuracy {
        max_accuracy_nm: acc * 1e3,
        max_repeatability_nm: rep * 1e3,
        poses: poses.len(),
    })
}

fn finite(v: f64) -> f64 {
    if v.is_finite() {
        v
    } else {
        0.0
    }
}

/// A value in nm as a person reads it (µm above 10 µm).
fn nm(v_nm: f64) -> String {
    length_um(v_nm * 1e-3)
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
                    summary: e.summary.clone(),
                    rms_before_nm: finite(e.rms_before_nm),
                    rms_after_nm: finite(e.rms_after_nm),
                    evidence: e.evidence.clone(),
                    play_operators: e.blob.as_ref().map_or(Vec::new(), |b| b.play.clone()),
                    lag_filters: e.blob.as_ref().map_or(Vec::new(), |b| b.lags.clone()),
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
        let channels = self
            .channels
            .iter()
            .map(|c| JsonChannel {
                axis: c.channel.clone(),
                headline: c.headline(),
                structure_remains: !c.unexplained.is_empty(),
                noise_floor_nm: finite(c.noise_floor.sample_um * 1e3),
                quantisation_nm: c.quant_step_um.map(|q| q * 1e3),
                outlier_rows: {
                    let mut rows: Vec<usize> = c
                        .outliers
                        .iter()
                        .chain(&c.model_outliers)
                        .map(|r| r + 1)
                        .collect();
                    rows.sort_unstable();
                    rows
                },
                baseline_rms_nm: finite(c.baseline_rms_nm),
                final_rms_nm: finite(c.final_rms_nm),
                events: c
                    .events
                    .iter()
                    .map(|e| JsonEvent {
                        row: e.row + 1,
                        row_range: [e.row_range.0 + 1, e.row_range.1 + 1],
                        t_s: e.t_s,
                        size_nm: e.size_um * 1e3,
                        size_sigma_nm: e.size_sigma_um * 1e3,
                    })
                    .collect(),
            })
            .collect();
        let data_faults = self
            .data_faults
            .iter()
            .map(|f| JsonFault {
                kind: f.kind,
                column: f.column.clone(),
                rows: f.rows.iter().map(|&(a, b)| [a + 1, b]).collect(),
                detail: f.detail.clone(),
                handling: f.handling.clone(),
                needs_check: f.kind.needs_check(),
            })
            .collect();
        let not_in_library = self
            .channels
            .iter()
            .flat_map(|c| {
                c.not_in_library.iter().map(move |m| JsonMisfit {
                    axis: c.channel.clone(),
                    coordinate: m.coordinate.clone(),
                    description: m.description.clone(),
                    rms_nm: finite(m.rms_nm),
                    withdrawn: m.withdrawn.iter().map(|w| w.to_string()).collect(),
                    evidence: m.evidence.clone(),
                })
            })
            .collect();
        JsonReport {
            baseline_rms_nm: finite(self.baseline_rms_nm()),
            channels,
            effects,
            unexplained,
            data_faults,
            not_in_library,
        }
    }

    /// The report for a person.
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        let (check, notes): (Vec<&DataFault>, Vec<&DataFault>) =
            self.data_faults.iter().partition(|f| f.kind.needs_check());
        if !check.is_empty() {
            let _ = writeln!(
                s,
                "data faults (a sensor or the logger to check — not physics; explain fits around them):"
            );
            for f in check {
                let _ = writeln!(
                    s,
                    "  - {} in {} (data rows {}): {}; {}",
                    f.kind,
                    f.column,
                    f.rows_in_words(),
                    f.detail,
                    f.handling
                );
            }
        }
        for f in notes {
            let _ = writeln!(
                s,
                "data note: {} in {}: {}; {}",
                f.kind, f.column, f.detail, f.handling
            );
        }
        for (name, rows) in &self.temp_repairs {
            let _ = writeln!(
                s,
                "glitches in {name} repaired by interpolation (data rows {})",
                rows_in_words(rows, 8)
            );
        }
        for c in &self.channels {
            let _ = writeln!(s, "── channel {} ({} rows)", c.channel, c.rows);
            let _ = writeln!(s, "  headline: {}", c.headline());
            let _ = writeln!(s, "  baseline: {}", c.baseline);
            let mut floor = format!(
                "  noise floor from the data: {} sample-to-sample, {} per independent unit",
                nm(c.noise_floor.sample_um * 1e3),
                nm(c.noise_floor.unit_um * 1e3)
            );
            if let Some(q) = c.quant_step_um {
                let _ = write!(
                    floor,
                    " (readings quantised in steps of {}: the floor is at least step/√12 = {})",
                    length_um(q),
                    length_um(q / 12f64.sqrt())
                );
            }
            if c.held {
                floor.push_str(" (the measurement is held between slower updates: scatter taken over the updates)");
            }
            let _ = writeln!(s, "{floor}");
            if !c.outliers.is_empty() {
                let _ = writeln!(
                    s,
                    "  outliers: {} row(s) jump away by up to {} and come back (glitches: a mis-trigger, a homing error, a dropped reading), excluded from fitting — data rows {}",
                    c.outliers.len(),
                    length_um(c.outlier_max_um),
                    rows_in_words(&c.outliers, 10)
                );
            }
            if !c.model_outliers.is_empty() {
                let _ = writeln!(
                    s,
                    "  outliers: {} row(s) that every model misses by more than 10 robust standard deviations of its held-out residual (a start-up transient, a reading taken while moving), excluded — data rows {}",
                    c.model_outliers.len(),
                    rows_in_words(&c.model_outliers, 10)
                );
            }
            let _ = writeln!(
                s,
                "  baseline RMS: {} held-out ({} in-sample)",
                nm(c.baseline_rms_nm),
                nm(c.baseline_in_sample_rms_nm)
            );
            if c.located.is_empty() {
                let _ = writeln!(s, "  locate: no structure above the noise floor");
            } else {
                let _ = writeln!(s, "  locate: structured residual");
                for f in c.located.iter().take(10) {
                    let _ = writeln!(
                        s,
                        "    - {} [{}]: mean {}, RMS {} ({:.0}σ)",
                        f.place,
                        f.dimension,
                        nm(f.mean_nm),
                        nm(f.rms_nm),
                        f.z
                    );
                }
            }
            for e in &c.events {
                let _ = writeln!(
                    s,
                    "  event: the response steps by {} ± {} at data row {} ({} after the start; the step lies in data rows {}–{}), abruptly (scan z {:.0}) — a slip, a re-seat or a collision, not a drift: check the mount; modelled as an offset from that row on ({})",
                    length_um(e.size_um),
                    length_um(e.size_sigma_um),
                    e.row + 1,
                    duration(e.t_s),
                    e.row_range.0 + 1,
                    e.row_range.1 + 1,
                    e.z,
                    e.evidence
                );
            }
            for e in &c.effects {
                let _ = writeln!(s, "  name: {} — {}", e.name, e.description);
                if !e.summary.is_empty() {
                    let _ = writeln!(s, "    found: {}", e.summary);
                }
                let ps: Vec<String> = e
                    .params
                    .iter()
                    .map(|p| {
                        if p.sigma.is_finite() && p.sigma > 0.0 {
                            format!("{} = {} ± {}", p.name, sig3(p.value), sig3(p.sigma))
                        } else if p.sigma.is_infinite() {
                            format!("{} = {} (not constrained)", p.name, sig3(p.value))
                        } else {
                            format!("{} = {}", p.name, sig3(p.value))
                        }
                    })
                    .collect();
                let _ = writeln!(s, "    parameters: {}", ps.join(", "));
                let _ = writeln!(s, "    evidence: {}", e.evidence);
                let _ = writeln!(s, "    compensator: {}", e.deploy);
                if let Some(b) = &e.blob {
                    let _ = writeln!(
                        s,
                        "    blob: {} term shape(s), {} lag filter(s), {} play operator(s)",
                        b.terms.len(),
                        b.lags.len(),
                        b.play.len()
                    );
                }
            }
            if !c.targeted.is_empty() {
                let parts: Vec<String> = c
                    .targeted
                    .iter()
                    .map(|t| {
                        format!(
                            "{}: {} ± {}{}, z {:.1}{}",
                            t.what,
                            sig3(t.amplitude),
                            sig3(t.amplitude_sigma),
                            if t.period_nm.is_some() {
                                " nm"
                            } else {
                                " ppm/°C"
                            },
                            t.z,
                            if t.significant {
                                " — significant"
                            } else if !t.halves_agree {
                                " (the halves disagree)"
                            } else {
                                ""
                            }
                        )
                    })
                    .collect();
                let _ = writeln!(
                    s,
                    "  targeted tests ({} % false alarms over all {} together): {}",
                    super::targeted::FAMILY_FALSE_ALARM * 100.0,
                    c.targeted.len(),
                    parts.join("; ")
                );
            }
            if let Some(last) = c.trials.last() {
                let rejected: Vec<String> = last
                    .iter()
                    .filter(|t| !t.passed)
                    .map(|t| {
                        if t.cv_rms_um.is_finite() {
                            format!(
                                "{} (ΔBIC {:.0}, held-out {}, {}/{} folds)",
                                t.name,
                                t.delta_bic,
                                nm(t.cv_rms_um * 1e3),
                                t.folds_better,
                                t.folds
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
                "  RMS held-out: before {} → after {}",
                nm(c.baseline_rms_nm),
                nm(c.final_rms_nm)
            );
            if let (Some(b), Some(a)) = (c.iso_before, c.iso_after) {
                let _ = writeln!(
                    s,
                    "  ISO 9283 (held-out, {} revisited pose/direction groups): accuracy {} → {}, repeatability {} → {}",
                    b.poses,
                    nm(b.max_accuracy_nm),
                    nm(a.max_accuracy_nm),
                    nm(b.max_repeatability_nm),
                    nm(a.max_repeatability_nm)
                );
            }
            if c.unexplained.is_empty() {
                let _ = writeln!(s, "  unexplained: nothing above the noise floor");
            } else {
                let _ = writeln!(s, "  unexplained (no candidate explains it):");
                for f in &c.unexplained {
                    if f.z.is_finite() {
                        let _ = writeln!(
                            s,
                            "    - {} [{}]: RMS {}, mean {} ({:.0}σ)",
                            f.place,
                            f.dimension,
                            nm(f.rms_nm),
                            nm(f.mean_nm),
                            f.z
                        );
                    } else {
                        let _ = writeln!(
                            s,
                            "    - not in the library: {} [{}]: held-out RMS it carries {}",
                            f.place,
                            f.dimension,
                            nm(f.rms_nm)
                        );
                    }
                }
                for m in &c.not_in_library {
                    let _ = writeln!(s, "    evidence ({}): {}", m.coordinate, m.evidence);
                }
            }
        }
        s
    }
}
