//! A campaign's state on disk (`DIR/campaign.json`, next to `plan.json`, the recording and the
//! model blobs): enough to pick a campaign of days up after the host restarted (`--resume`).
//! Written after every step, atomically (a temporary file renamed over the old one), so a crash
//! at any instant leaves either the old state or the new one.

use super::recorder::Layout;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// State format version. 2: the plan's schedule changed (issue 18: the KMZ is the first visit of
/// an adaptive test, paper 000's tests take 1.25 h, visits are labelled by the motion that
/// reached them), the fold period, the first KMZ reading and the validate-and-return loop.
pub const VERSION: u32 = 2;
/// The fold period of a state that does not record one (the firmware's default).
fn default_fold_period_ms() -> u16 {
    nanocal_interface::settings::DEFAULT_FOLD_PERIOD_MS
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
        /// The board the firmware runs on (absent in a state written before there was a
        /// choice, and for QEMU, so those states keep their bytes).
        #[serde(default, skip_serializing_if = "VirtualBoard::is_qemu")]
        board: VirtualBoard,
    },
}

/// The board under the virtual bench's firmware.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VirtualBoard {
    /// The QEMU `mps2-an386` board with the QEMU firmware (in this process's library).
    #[default]
    Qemu,
    /// The emulated B-L475E-IOT01A with the shipped STM32 image: GPL (it links Unicorn), so it
    /// runs in its own process, the `stm32-bench` binary.
    Stm32,
}

impl VirtualBoard {
    /// The default board.
    pub fn is_qemu(&self) -> bool {
        *self == VirtualBoard::Qemu
    }

    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            VirtualBoard::Qemu => "qemu",
            VirtualBoard::Stm32 => "stm32",
        }
    }
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

/// The compensator raised `MODEL_STALE` on the model in service (`nanocal_compensator::stale`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StaleEvent {
    /// Plan time when it rose, s (the device's time of the rise, on the plan's clock).
    pub rose_s: f64,
    /// The first step, from the one during which the campaign saw it, that uses the model (a
    /// model is set up in the hold of the step before: its rise may show one step early).
    pub step: usize,
    /// What that step is (e.g. `test 19/93 (static)`).
    pub during: String,
    /// The model it concerns: `static`, `adaptive` or its id in hex.
    pub model: String,
    /// The blob CRC of that model (tells two uploads of a model apart from two rises).
    pub model_crc32: u32,
    /// Why, in words (`nanocal_interface::status::StaleReasons`).
    pub reasons: String,
    /// Temperatures beyond the training envelope when seen, °C (≤ 0 inside; None: the model
    /// reads none).
    pub envelope_excess_c: Option<f32>,
    /// The device's uptime at the rise, ms (with `model_crc32`, what tells rises apart).
    pub since_ms: u32,
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
    /// The model this campaign uploaded last, as the device confirmed it: in service while
    /// the device's status shows its id and blob CRC (a state file without it: none).
    #[serde(default)]
    pub uploaded: Option<UploadedModel>,
    /// λ_KMZ per axis last measured and sent to the compensator, µm.
    pub kmz_um: Option<Vec<f64>>,
    /// The first KMZ re-measurement, which later ones are differences to
    /// ([`crate::data::kmz::KmzDrift`]).
    #[serde(default)]
    pub kmz_first: Option<crate::data::kmz::KmzReading>,
    /// KMZ re-measurements so far.
    pub kmz_updates: usize,
    /// Device resets seen.
    pub device_resets: usize,
    /// Interruptions so far.
    pub interruptions: Vec<Interruption>,
    /// Every rise of the compensator's `MODEL_STALE` seen, in order.
    #[serde(default)]
    pub stale: Vec<StaleEvent>,
    /// The validate-and-return loop (paper 001 §II step 5), when a target accuracy was given.
    #[serde(default)]
    pub loops: Option<LoopState>,
}

/// The validate-and-return loop of paper 001 §II step 5: "Validation (evaluation of the robot
/// absolute accuracy) and eventually return to 1. (if the desired absolute accuracy has not yet
/// been reached and consider other sources of inaccuracy), or return to 0. (if all the possible
/// sources of inaccuracy have already been considered)".
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LoopState {
    /// The desired accuracy: the worst test's Acc of the static model, nm.
    pub target_nm: f64,
    /// Tests in each loop's validation block.
    pub tests_per_block: usize,
    /// Most loops to run.
    pub max_loops: usize,
    /// The loops started, in order.
    pub loops: Vec<LoopRecord>,
    /// Validations decided on (0: none; 1: the plan's; 1 + l: loop l's block too).
    pub decided: usize,
    /// Why the loop stopped, once it did.
    pub stop: Option<LoopStop>,
}

/// One loop: what was added, the model, its validation block and what it showed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LoopRecord {
    /// What explain named and the model now carries (lag filters, play operators, terms).
    pub added: Vec<crate::fit::design::Extension>,
    /// explain's words on each, with its held-out RMS before → after, on the validation the
    /// loop started from.
    pub evidence: Vec<String>,
    /// Id of the refitted static model (its blob: `static-<loop>.blob`).
    pub model_id: u32,
    /// Terms selected, geometric + thermal + other (offsets excluded).
    pub parameters: (usize, usize, usize),
    /// The static model's worst test accuracy on the validation the loop started from, nm.
    pub acc_from_nm: f64,
    /// Once its block ran: the previous static model evaluated on the block's data (open loop:
    /// the same commands, never used for a fit).
    pub before: Option<BlockAccuracy>,
    /// Once its block ran: this loop's model through the firmware.
    pub after: Option<BlockAccuracy>,
    /// Once its block ran: the largest difference between its table from what the stage
    /// received and the file-based validation of the same rows, nm.
    pub agreement_nm: Option<f64>,
    /// Once its block ran: visits with a temperature outside the training range, of all.
    pub outside_training: Option<(usize, usize)>,
}

/// A static model's accuracy over a block of tests.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BlockAccuracy {
    /// The mean over tests of the test accuracy (Eq. 6: max over its poses) — the numerator
    /// of paper 000's time robustness, Eq. 21 — nm. The loop's held-out measure.
    pub mean_nm: f64,
    /// The worst test's accuracy, nm.
    pub worst_nm: f64,
}

/// Why the loop stopped.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LoopStop {
    /// The desired accuracy is met.
    TargetMet {
        /// Worst test Acc, nm.
        acc_nm: f64,
    },
    /// The last loop did not improve held-out accuracy (the mean test accuracy of its block):
    /// its model is not kept.
    NoImprovement {
        /// The previous model on the last block, nm.
        before_nm: f64,
        /// The last loop's model on it, nm.
        after_nm: f64,
        /// What to change, in words (e.g. training over the range of use).
        advice: Vec<String>,
    },
    /// What remains needs a design change (step 0): explain named nothing the blob can carry.
    DesignChange {
        /// What to change, in words (a sensor where, a source with no input).
        advice: Vec<String>,
    },
    /// The most loops allowed ran.
    MaxLoops,
}

/// A model the campaign uploaded: its id and the CRC-32 its blob carries (the content hash
/// the device reports with the id).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct UploadedModel {
    /// The model's id.
    pub model_id: u32,
    /// The CRC-32 its blob carries.
    pub model_crc32: u32,
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

    /// A QEMU campaign's bench keeps the bytes it had before boards were a choice (and an older
    /// state reads as QEMU); an STM32 one names its board and reads back as such.
    #[test]
    fn the_virtual_board_is_named_only_when_it_is_the_stm32() {
        let qemu = BenchSpec::Virtual {
            seed: 3,
            board: VirtualBoard::Qemu,
        };
        let text = serde_json::to_string(&qemu).unwrap();
        assert_eq!(text, r#"{"virtual":{"seed":3}}"#);
        assert_eq!(serde_json::from_str::<BenchSpec>(&text).unwrap(), qemu);
        let stm32 = BenchSpec::Virtual {
            seed: 3,
            board: VirtualBoard::Stm32,
        };
        let text = serde_json::to_string(&stm32).unwrap();
        assert_eq!(text, r#"{"virtual":{"seed":3,"board":"stm32"}}"#);
        assert_eq!(serde_json::from_str::<BenchSpec>(&text).unwrap(), stm32);
    }

    #[test]
    fn state_round_trips_and_a_foreign_file_is_refused() {
        let dir = std::env::temp_dir().join(format!("nanocal-state-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let s = State {
            version: VERSION,
            bench: BenchSpec::Virtual {
                seed: 3,
                board: VirtualBoard::Qemu,
            },
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
            uploaded: Some(UploadedModel {
                model_id: 2,
                model_crc32: 0x89AB_CDEF,
            }),
            kmz_um: Some(vec![0.125]),
            kmz_first: None,
            kmz_updates: 1,
            loops: None,
            device_resets: 0,
            interruptions: vec![Interruption {
                step: 17,
                plan_time_s: 374.0,
                what: "Ctrl-C".into(),
            }],
            stale: vec![StaleEvent {
                rose_s: 250_000.5,
                step: 16,
                during: "test 19/93 (static)".into(),
                model: "static".into(),
                model_crc32: 0x89AB_CDEF,
                reasons: "a temperature left the training envelope".into(),
                envelope_excess_c: Some(0.125),
                since_ms: 1234,
            }],
        };
        s.save(&dir).unwrap();
        assert_eq!(State::load(&dir).unwrap(), s);
        std::fs::write(dir.join(FILE), "{\"plan\": 1}").unwrap();
        assert!(matches!(State::load(&dir), Err(StateError::Format { .. })));
        std::fs::remove_dir_all(&dir).ok();
    }
}
