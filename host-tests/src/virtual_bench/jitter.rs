//! The command jitter the device's slow path puts on commands, measured through the QEMU
//! firmware on the virtual bench.
//!
//! A stage at one pose in a room held constant; four type K thermocouples read by MAX31856
//! chips with the datasheet's noise (≈ 16 mK a reading, [`crate::twin::examples`]); paper 000's
//! static model (Table 1: b = 2.978, −3.142, −0.996, 0.690 µm/°C, so a reading's noise moves
//! the command by ‖b‖·16 mK ≈ 72 nm) uploaded to the firmware; `MOV 1 240` sent again and again,
//! and the commands the simulated controller received collected. Their standard deviation is
//! the jitter: the thermal fold's noise, nothing else (the true temperatures do not change).
//! Averaging the readings of a fold period divides it by √(readings a fold)
//! ([`nanocal_compensator::slow_average`]; paper 001 §VI: thermal terms "each 5-10 seconds").

use super::bench::{Faults, VirtualBench};
use crate::campaign::bench::BenchDriver;
use crate::campaign::gcs::GcsLink;
use crate::device::Client;
use crate::twin::{Dwell, Trajectory, Twin};
use nanocal_compensator::sensor::Chip;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

/// The device's slow-path periods of one measurement, ms.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Periods {
    /// Sensor sample period.
    pub sample_ms: u16,
    /// Fold period (readings averaged over it).
    pub fold_ms: u16,
}

/// One measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Jitter {
    /// The periods.
    pub periods: Periods,
    /// Commands collected.
    pub moves: usize,
    /// Standard deviation of the commands, nm.
    pub sigma_nm: f64,
    /// What the readings' noise predicts: ‖b‖ · σ_reading / √(readings a fold), nm.
    pub expected_nm: f64,
}

/// Pose of the measurement, µm.
const POSE_UM: f64 = 240.0;

/// The published stage's sensors in a room that does not change (the temperatures stay at
/// 22 °C: only the readings' noise moves the command).
fn quiet_twin(seed: u64) -> Twin {
    let mut cfg = crate::twin::examples::paper000_1dof_controlled_twin(seed).cfg;
    cfg.room.mean_c = 22.0;
    cfg.room.daily_amplitude_c = 0.0;
    cfg.room.hvac_amplitude_c = 0.0;
    cfg.room.steps_per_day = 0.0;
    cfg.room.trend_c_per_day = 0.0;
    cfg.room.ramps.clear();
    cfg.effects.clear();
    for s in cfg.sensors.iter_mut() {
        s.offset_c = 0.0;
        s.local_heater_c = 0.0;
    }
    Twin::new(cfg, 86_400.0, seed)
}

/// Reading noise of the sensors, °C RMS (the same for each).
fn reading_noise_c(twin: &Twin) -> f64 {
    twin.cfg
        .sensors
        .iter()
        .filter(|s| s.recorded)
        .map(|s| s.noise_c)
        .fold(0.0, f64::max)
}

/// Measures the jitter for each of `periods`, `moves` commands `every_s` apart (after one fold
/// period for the averages to fill), on one virtual bench booted with `seed`.
pub fn measure(
    periods: &[Periods],
    moves: usize,
    every_s: f64,
    seed: u64,
) -> Result<Vec<Jitter>, String> {
    let twin = quiet_twin(seed);
    let span_s = periods.len() as f64 * (moves as f64 + 20.0) * every_s + 600.0;
    let traj = Trajectory {
        dwells: vec![Dwell {
            cmd_um: vec![POSE_UM],
            dwell_s: span_s,
        }],
    };
    let mut vb = VirtualBench::start(&twin, &traj, 0.0, seed, -30.0, &Faults::default());
    let mut device = Client::new(
        vb.management(),
        "virtual:management",
        Duration::from_secs(10),
    );
    let mut gcs = GcsLink::new(vb.gcs(), "virtual:gcs");
    let stop = AtomicBool::new(false);
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let model = crate::papers::published::published_1dof().map_err(|m| format!("{m:?}"))?;
    let b = crate::papers::published::one_dof::B_UM_PER_C;
    let b_norm = b.iter().map(|v| v * v).sum::<f64>().sqrt();
    let sigma_c = reading_noise_c(&twin);
    let sensors = twin.cfg.sensors.iter().filter(|s| s.recorded).count();
    let mut out = Vec::new();
    let mut t = 0.0;
    for p in periods {
        let mut r = Ok(());
        let blob = crate::fit::encode_blob(&model);
        vb.exchange(&mut || {
            r = (|| {
                let mut s = device.config()?;
                for (i, slot) in s.sensors.iter_mut().enumerate() {
                    *slot = (i < sensors).then_some(Chip::K);
                }
                s.aux = Default::default();
                s.sample_period_ms = p.sample_ms;
                s.fold_period_ms = p.fold_ms;
                device.set_config(&s)?;
                device.upload(&blob)?;
                device.bypass(false)
            })();
        })
        .map_err(|x| e(&x))?;
        r.map_err(|x| e(&x))?;
        // the averages of a whole fold period before the first move
        t += 2.0 * f64::from(p.fold_ms.max(p.sample_ms)) / 1000.0 + 2.0;
        vb.wait_until(t, &stop).map_err(|x| e(&x))?;
        vb.stage_commands();
        let mut q = Vec::with_capacity(moves);
        for _ in 0..moves {
            let mut code = Ok(0);
            vb.exchange(&mut || {
                code = gcs
                    .send(&format!("MOV 1 {POSE_UM}"))
                    .and_then(|_| gcs.error());
            })
            .map_err(|x| e(&x))?;
            match code.map_err(|x| e(&x))? {
                0 => {}
                c => return Err(format!("MOV refused with GCS error {c}")),
            }
            t += every_s;
            vb.wait_until(t, &stop).map_err(|x| e(&x))?;
            if let Some(c) = vb.stage_commands().and_then(|c| c.last().cloned()) {
                q.push(c.1[0]);
            }
        }
        if q.len() < 2 {
            return Err("the controller received no commands".into());
        }
        let m = q.iter().sum::<f64>() / q.len() as f64;
        let sd = (q.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (q.len() - 1) as f64).sqrt();
        let readings = (f64::from(p.fold_ms) / f64::from(p.sample_ms))
            .max(1.0)
            .floor();
        out.push(Jitter {
            periods: *p,
            moves: q.len(),
            sigma_nm: sd * 1e3,
            expected_nm: b_norm * sigma_c / readings.sqrt() * 1e3,
        });
    }
    Ok(out)
}
