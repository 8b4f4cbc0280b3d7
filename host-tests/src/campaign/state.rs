//! A campaign's state on disk (`DIR/campaign.json`, next to `plan.json`, the recording and the
//! model blobs): enough to pick a campaign of days up after the host restarted (`--resume`).
//! Written after every step, atomically (a temporary file renamed over the old one), so a crash
//! at any instant leaves either the old state or the new one.

use super::recorder::Layout;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// State format version.
pub const VERSION: u32 = 1;
/// The fold period of a state that does not record one (the firmware's default).
fn default_fold_period_ms() -> u16 {
    nanocal_compensator::settings::DEFAULT_FOLD_PERIOD_MS
}

/// File name of the state in the campaign's folder.
pub const FILE: &str = "campaign.json";

/// Where the campaign runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BenchSpec {
    /// A real bench.
    Real {
        /// The compensator's management port.
        device: String,
        /// The compensator's GCS port.
        gcs: String,
        /// The reference instrument.
        reference: String,
        /// Positions from the instrument are multiplied by this to give µm.
        reference_to_um: f64,
        /// The instrument stamps samples on the host's clock already.
        reference_synchronized: bool,
    },
    /// The virtual bench.
    Virtual {
        /// Seed of the twin's room and noise.
        seed: u64,
    },
}

/// Where the campaign stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
    /// Running the plan's steps.
    Steps,
    /// Every step done: validation statistics, report, explain.
    Analysis,
    /// Finished.
    Done,
}

/// An interruption (Ctrl-C, an error, a device reset) and where it happened.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Interruption {
    /// The step that was under way.
    pub step: usize,
    /// Plan time, s.
    pub plan_time_s: f64,
    /// What happened.
    pub what: String,
}

/// The state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct State {
    /// Format version.
    pub version: u32,
    /// The bench.
    pub bench: BenchSpec,
    /// The recording's columns.
    pub layout: Layout,
    /// The compensator's sample period, ms.
    pub sample_period_ms: u16,
    /// The compensator's fold period, ms (readings averaged over it).
    #[serde(default = "default_fold_period_ms")]
    pub fold_period_ms: u16,
    /// Where the stage is left when the campaign stops early, µm per axis.
    pub safe_pose_um: Vec<f64>,
    /// First step not yet completed.
    pub next_step: usize,
    /// Length of the recording at the end of the last completed step, bytes.
    pub recording_bytes: u64,
    /// Where the campaign stands.
    pub stage: Stage,
    /// Model ids once fitted: (static, adaptive).
    pub model_ids: Option<(u32, u32)>,
    /// λ_KMZ per axis last measured and sent to the compensator, µm.
    pub kmz_um: Option<Vec<f64>>,
    /// The first KMZ re-measurement, which later ones are differences to
    /// ([`crate::kmz::KmzDrift`]).
    #[serde(default)]
    pub kmz_first: Option<crate::kmz::KmzReading>,
    /// KMZ re-measurements so far.
    pub kmz_updates: usize,
    /// Device resets seen.
    pub device_resets: usize,
    /// Interruptions so far.
    pub interruptions: Vec<Interruption>,
}

/// Errors of the state file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StateError {
    /// Reading or writing failed.
    #[error("campaign state {path}: {cause}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        cause: std::io::Error,
    },
    /// The file is not a campaign state.
    #[error("campaign state {path}: {cause}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        cause: String,
    },
}

impl State {
    /// Read the state in `dir`.
    pub fn load(dir: &Path) -> Result<State, StateError> {
        let path = dir.join(FILE);
        let text = std::fs::read_to_string(&path).map_err(|cause| StateError::Io {
            path: path.clone(),
            cause,
        })?;
        let s: State = serde_json::from_str(&text).map_err(|e| StateError::Format {
            path: path.clone(),
            cause: e.to_string(),
        })?;
        if s.version != VERSION {
            return Err(StateError::Format {
                path,
                cause: format!("version {} (this nanocal writes {VERSION})", s.version),
            });
        }
        Ok(s)
    }

    /// Write the state into `dir` atomically.
    pub fn save(&self, dir: &Path) -> Result<(), StateError> {
        let path = dir.join(FILE);
        let tmp = dir.join(format!("{FILE}.tmp"));
        let io = |cause| StateError::Io {
            path: path.clone(),
            cause,
        };
        let text = serde_json::to_string_pretty(self).map_err(|e| StateError::Format {
            path: path.clone(),
            cause: e.to_string(),
        })?;
        std::fs::write(&tmp, text).map_err(io)?;
        std::fs::rename(&tmp, &path).map_err(io)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn state_round_trips_and_a_foreign_file_is_refused() {
        let dir = std::env::temp_dir().join(format!("nanocal-state-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let s = State {
            version: VERSION,
            bench: BenchSpec::Virtual { seed: 3 },
            layout: Layout {
                axes: vec!["x".into()],
                temps: vec!["cs0".into()],
                aux: vec![],
            },
            sample_period_ms: 1000,
            fold_period_ms: 5000,
            safe_pose_um: vec![0.0],
            next_step: 17,
            recording_bytes: 12345,
            stage: Stage::Steps,
            model_ids: Some((1, 2)),
            kmz_um: Some(vec![0.125]),
            kmz_first: None,
            kmz_updates: 1,
            device_resets: 0,
            interruptions: vec![Interruption {
                step: 17,
                plan_time_s: 374.0,
                what: "Ctrl-C".into(),
            }],
        };
        s.save(&dir).unwrap();
        assert_eq!(State::load(&dir).unwrap(), s);
        std::fs::write(dir.join(FILE), "{\"plan\": 1}").unwrap();
        assert!(matches!(State::load(&dir), Err(StateError::Format { .. })));
        std::fs::remove_dir_all(&dir).ok();
    }
}
