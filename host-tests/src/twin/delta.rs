//! A 3-DoF parallel-kinematic robot like paper 001's Agietron Micro-Nano (§I.A): a linear delta
//! — three vertical actuators at 120°, each carrying a flexure-hinge parallelogram arm to the
//! effector — in titanium, with 10 nm encoders and a ≈ 1 cm³ workspace, measured by three
//! interferometers (SIOS SP-2000, ≈ 1.24 nm resolution) on a five-facet mirror cube (§IV.A),
//! with 7 temperature sensors glued on the structure and 3 in the air near the interferometer
//! beams (§IV.B, Fig. 7).
//!
//! The robot is commanded in motor coordinates `m` (µm of carriage travel as the encoders count
//! it). Its true geometry differs from the nominal one by manufacturing and assembly tolerances
//! (carriage home points, column tilts, effector joints, arm lengths, encoder scales and
//! offsets), and changes with the temperature of each part (titanium, α = 8.6 ppm/K): arm
//! lengths, column heights and encoder scales, base radius, effector size (no sensor on the
//! effector). The interferometers read the effector's position with the air's refractive index
//! changing with the air temperature near each beam (−0.93 ppm/K over the dead path plus the
//! displacement), and the robot base moves against the interferometer frame as the base warms.
//! As in paper 001 (§VII.A: "in motor coordinates"), the measured pose is expressed in motor
//! coordinates through the *nominal* inverse geometric model: `meas_m_i = IGM_nom(x_meas)_i`.
//!
//! Each move ends within the encoder resolution (10 nm) of the command, with a positioning
//! scatter of the servo and flexures and a small hysteresis of the flexure hinges by direction
//! of approach. A recording has `t`, `cmd_m1..3`, `meas_m1..3` (µm) and the ten `temp_*`
//! columns.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::room::{quantize, Room, RoomConfig, SensorConfig};
use super::{normal, Columns, Trajectory};

/// Motor axis names (`cmd_m1`, `meas_m1`, …).
pub const MOTOR_AXES: [&str; 3] = ["m1", "m2", "m3"];

/// Thermal expansion of titanium (Ti-6Al-4V), 1/K.
pub const ALPHA_TITANIUM_PER_K: f64 = 8.6e-6;

/// Change of the refractive index of air with temperature near 20 °C and 101.3 kPa, 1/K
/// (Edlén's formula as revised by Birch and Downs: dn/dT ≈ −0.93 × 10⁻⁶ K⁻¹).
pub const DN_DT_AIR_PER_K: f64 = -0.93e-6;

/// The geometry of one actuator chain.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Chain {
    /// Carriage joint at motor coordinate 0, mm.
    pub home_mm: [f64; 3],
    /// Unit direction of the actuator's travel.
    pub column: [f64; 3],
    /// Effector joint relative to the effector's reference point, mm.
    pub joint_mm: [f64; 3],
    /// Arm (parallelogram) length, mm.
    pub arm_mm: f64,
    /// Encoder scale error: true travel = (1 + scale) × counted travel + offset.
    pub scale: f64,
    /// Encoder offset, mm.
    pub offset_mm: f64,
}

/// The three chains of a delta robot.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DeltaGeometry {
    /// One chain per actuator.
    pub chains: [Chain; 3],
}

impl DeltaGeometry {
    /// The nominal geometry: columns at 90°, 210°, 330° on a 50 mm radius, effector joints on a
    /// 15 mm radius, 60 mm arms; motor coordinate 0 puts the effector at the origin.
    pub fn nominal() -> Self {
        let (base_r, eff_r, arm): (f64, f64, f64) = (50.0, 15.0, 60.0);
        let z0 = (arm * arm - (base_r - eff_r) * (base_r - eff_r)).sqrt();
        let chain = |deg: f64| {
            let (s, c) = deg.to_radians().sin_cos();
            Chain {
                home_mm: [base_r * c, base_r * s, z0],
                column: [0.0, 0.0, 1.0],
                joint_mm: [eff_r * c, eff_r * s, 0.0],
                arm_mm: arm,
                scale: 0.0,
                offset_mm: 0.0,
            }
        };
        DeltaGeometry {
            chains: [chain(90.0), chain(210.0), chain(330.0)],
        }
    }

    /// Inverse geometric model: motor coordinates (mm) of the effector at `p_mm`; NaN where the
    /// pose cannot be reached.
    pub fn inverse_mm(&self, p_mm: [f64; 3]) -> [f64; 3] {
        let mut m = [0.0; 3];
        for (i, c) in self.chains.iter().enumerate() {
            let d: [f64; 3] = std::array::from_fn(|a| p_mm[a] + c.joint_mm[a] - c.home_mm[a]);
            let wd: f64 = (0..3).map(|a| c.column[a] * d[a]).sum();
            let dd: f64 = d.iter().map(|v| v * v).sum();
            let travel = wd + (wd * wd - dd + c.arm_mm * c.arm_mm).sqrt();
            m[i] = (travel - c.offset_mm) / (1.0 + c.scale);
        }
        m
    }

    /// Forward geometric model: the effector position (mm) for motor coordinates `m_mm`, by
    /// Newton's method on the inverse model from `start_mm`.
    pub fn forward_mm(&self, m_mm: [f64; 3], start_mm: [f64; 3]) -> [f64; 3] {
        let mut p = start_mm;
        for _ in 0..20 {
            let r = self.inverse_mm(p);
            let res: [f64; 3] = std::array::from_fn(|i| r[i] - m_mm[i]);
            if res.iter().all(|v| v.abs() < 1e-13) {
                break;
            }
            let h = 1e-6;
            let mut jac = [[0.0; 3]; 3];
            for a in 0..3 {
                let mut q = p;
                q[a] += h;
                let rq = self.inverse_mm(q);
                for i in 0..3 {
                    jac[i][a] = (rq[i] - r[i]) / h;
                }
            }
            let step = solve3(jac, res);
            for a in 0..3 {
                p[a] -= step[a];
            }
        }
        p
    }

    /// This geometry with every part at its temperature change from the reference (K): arms,
    /// columns (travel origin height and encoder scale), base (radius), effector (joint radius).
    pub fn at_temperatures(&self, t: &PartTemperatures) -> Self {
        let a = ALPHA_TITANIUM_PER_K;
        let mut g = *self;
        for (i, c) in g.chains.iter_mut().enumerate() {
            c.arm_mm *= 1.0 + a * t.arm_k[i];
            // the column grows from the base plate: the carriage's home rises with it
            c.home_mm[2] += a * COLUMN_HEIGHT_MM * t.column_k[i];
            // the encoder scale is on the column and grows with it
            c.scale += a * t.column_k[i];
            c.home_mm[0] *= 1.0 + a * t.base_k;
            c.home_mm[1] *= 1.0 + a * t.base_k;
            for v in c.joint_mm.iter_mut() {
                *v *= 1.0 + a * t.effector_k;
            }
        }
        g
    }
}

/// Height of a column above the base plate, mm.
const COLUMN_HEIGHT_MM: f64 = 100.0;
/// Distance of the robot's origin from the interferometer frame's fixed point, per axis, mm
/// (what the base plate's expansion moves).
const FRAME_DISTANCE_MM: [f64; 3] = [60.0, 60.0, 100.0];
/// Interferometer dead path (beam length in air at zero displacement), mm.
const DEAD_PATH_MM: f64 = 100.0;

/// Temperature changes of the robot's parts from the reference, K.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PartTemperatures {
    /// Each arm.
    pub arm_k: [f64; 3],
    /// Each column (actuator).
    pub column_k: [f64; 3],
    /// The base plate.
    pub base_k: f64,
    /// The effector (no sensor on it).
    pub effector_k: f64,
}

/// Solves a 3×3 system by Cramer's rule.
fn solve3(j: [[f64; 3]; 3], r: [f64; 3]) -> [f64; 3] {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(j);
    std::array::from_fn(|k| {
        let mut m = j;
        for i in 0..3 {
            m[i][k] = r[i];
        }
        det(m) / d
    })
}

/// Everything that defines the simulated robot, its room and its instruments.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DeltaConfig {
    /// The true geometry at the reference temperature.
    pub geometry: DeltaGeometry,
    /// Reference temperature of the geometry, °C.
    pub temp_ref_c: f64,
    /// The room.
    pub room: RoomConfig,
    /// The spots, in this order: arm 1–3, column 1–3, base, air near the x, y, z beams
    /// (recorded), effector (unsensed).
    pub spots: Vec<SensorConfig>,
    /// Encoder resolution, nm.
    pub encoder_resolution_nm: f64,
    /// Positioning scatter of servo and flexures, a fresh offset per move and motor, nm (1 σ).
    pub positioning_sigma_nm: f64,
    /// Flexure hinge hysteresis: ± this by direction of approach of each motor, nm.
    pub hysteresis_nm: f64,
    /// Interferometer white noise per sample and axis, nm (1 σ).
    pub interferometer_noise_nm: f64,
    /// Interferometer resolution, nm.
    pub interferometer_resolution_nm: f64,
    /// Sample period, s.
    pub sample_period_s: f64,
}

/// Spot indices in [`DeltaConfig::spots`].
const ARMS: [usize; 3] = [0, 1, 2];
const COLUMNS: [usize; 3] = [3, 4, 5];
const BASE: usize = 6;
const AIR: [usize; 3] = [7, 8, 9];
const EFFECTOR: usize = 10;

impl DeltaConfig {
    /// The robot of paper 001 with manufacturing tolerances drawn from `seed`: carriage home
    /// points ±20 µm, column tilts 200 µrad, effector joints 10 µm, arm lengths 15 µm, encoder
    /// scales 50 ppm and offsets 20 µm (1 σ each). Its room swings ±0.25 °C a day (the
    /// temperatures must vary over the range of use while measuring, §IV.C); the structure's
    /// sensors are Pt1000 and the air's Pt100 read by a Keithley 2700 (1 mK resolution, 2 mK
    /// noise); the parts follow the room with lags of 20 min to 1 h, the air near the beams
    /// within a minute.
    pub fn paper001(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xDE17_A000);
        let mut g = DeltaGeometry::nominal();
        for c in g.chains.iter_mut() {
            for v in c.home_mm.iter_mut() {
                *v += 0.020 * normal(&mut rng);
            }
            let tilt = [200e-6 * normal(&mut rng), 200e-6 * normal(&mut rng)];
            let n = (1.0 + tilt[0] * tilt[0] + tilt[1] * tilt[1]).sqrt();
            c.column = [tilt[0] / n, tilt[1] / n, 1.0 / n];
            for v in c.joint_mm.iter_mut() {
                *v += 0.010 * normal(&mut rng);
            }
            c.arm_mm += 0.015 * normal(&mut rng);
            c.scale = 50e-6 * normal(&mut rng);
            c.offset_mm = 0.020 * normal(&mut rng);
        }
        let mut spots = Vec::new();
        for (part, tau_base_s) in [("arm", 1200.0), ("column", 2400.0)] {
            for i in 1..=3 {
                let off = 0.05 * rng.gen_range(-1.0..1.0);
                spots.push(SensorConfig::new(
                    &format!("{part}_{i}"),
                    off,
                    tau_base_s + 300.0 * i as f64,
                    1.0,
                ));
            }
        }
        spots.push(SensorConfig::new("base", 0.0, 3600.0, 0.9));
        for axis in ["x", "y", "z"] {
            spots.push(SensorConfig::new(&format!("air_{axis}"), 0.1, 60.0, 1.0));
        }
        spots.push(SensorConfig::unsensed("effector", 0.0, 1800.0, 1.0));
        DeltaConfig {
            geometry: g,
            temp_ref_c: 20.0,
            room: RoomConfig {
                daily_amplitude_c: 0.25,
                steps_per_day: 6.0,
                step_sigma_c: 0.05,
                ..RoomConfig::default()
            },
            spots,
            encoder_resolution_nm: 10.0,
            positioning_sigma_nm: 15.0,
            hysteresis_nm: 5.0,
            interferometer_noise_nm: 2.0,
            interferometer_resolution_nm: 1.24,
            sample_period_s: 1.0,
        }
    }
}

/// The robot twin: a configuration and a realised room.
#[derive(Debug, Clone)]
pub struct DeltaTwin {
    /// The configuration.
    pub cfg: DeltaConfig,
    room: Room,
    seed: u64,
}

impl DeltaTwin {
    /// Realises the room for `span_s` seconds of absolute time from `seed`.
    pub fn new(cfg: DeltaConfig, span_s: f64, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let room = Room::new(&cfg.room, span_s, &mut rng);
        DeltaTwin { cfg, room, seed }
    }

    /// Simulates the motor-coordinate trajectory `traj` (µm) from absolute time `start_s`.
    pub fn simulate(&self, traj: &Trajectory, start_s: f64, stream: u64) -> Columns {
        let cfg = &self.cfg;
        assert_eq!(traj.axes(), 3, "the delta robot has three motors");
        let mut rng =
            ChaCha8Rng::seed_from_u64(self.seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let (t_s, cmd_um) = traj.sample(cfg.sample_period_s);
        let n = t_s.len();
        let t_abs: Vec<f64> = t_s.iter().map(|t| t + start_s).collect();
        let spot_c = self
            .room
            .spots(&cfg.room, &cfg.spots, &t_s, &t_abs, start_s);
        let nominal = DeltaGeometry::nominal();
        let res_um = cfg.encoder_resolution_nm * 1e-3;
        let mut meas_um = vec![vec![0.0; n]; 3];
        let mut scatter = [0.0; 3];
        let mut dir = [1.0; 3];
        let mut p = [0.0; 3];
        for k in 0..n {
            for i in 0..3 {
                let moved = k == 0 || cmd_um[i][k] != cmd_um[i][k - 1];
                if moved {
                    if k > 0 {
                        dir[i] = (cmd_um[i][k] - cmd_um[i][k - 1]).signum();
                    }
                    scatter[i] = cfg.positioning_sigma_nm * 1e-3 * normal(&mut rng);
                }
            }
            // where the motors are: the command to the encoder's resolution, scatter, hysteresis
            let m_mm: [f64; 3] = std::array::from_fn(|i| {
                (quantize(cmd_um[i][k], res_um) + scatter[i] + dir[i] * cfg.hysteresis_nm * 1e-3)
                    * 1e-3
            });
            let dt = |s: usize| spot_c[s][k] - cfg.temp_ref_c;
            let parts = PartTemperatures {
                arm_k: ARMS.map(dt),
                column_k: COLUMNS.map(dt),
                base_k: dt(BASE),
                effector_k: dt(EFFECTOR),
            };
            p = cfg.geometry.at_temperatures(&parts).forward_mm(m_mm, p);
            // what the interferometers read, in the frame they define
            let read_mm: [f64; 3] = std::array::from_fn(|a| {
                let frame = -ALPHA_TITANIUM_PER_K * FRAME_DISTANCE_MM[a] * parts.base_k;
                let air = DN_DT_AIR_PER_K * (DEAD_PATH_MM + p[a]) * dt(AIR[a]);
                let noise = cfg.interferometer_noise_nm * 1e-6 * normal(&mut rng);
                quantize(
                    p[a] + frame + air + noise,
                    cfg.interferometer_resolution_nm * 1e-6,
                )
            });
            let m_meas = nominal.inverse_mm(read_mm);
            for i in 0..3 {
                meas_um[i][k] = m_meas[i] * 1e3;
            }
        }
        let mut columns = vec![("t".to_string(), t_s)];
        for (i, c) in cmd_um.into_iter().enumerate() {
            columns.push((format!("cmd_{}", MOTOR_AXES[i]), c));
        }
        for (i, m) in meas_um.into_iter().enumerate() {
            columns.push((format!("meas_{}", MOTOR_AXES[i]), m));
        }
        for (s, spot) in cfg.spots.iter().zip(&spot_c) {
            if !s.recorded {
                continue;
            }
            let read = spot
                .iter()
                .map(|&v| quantize(v + s.noise_c * normal(&mut rng), s.resolution_c))
                .collect();
            columns.push((format!("temp_{}", s.name), read));
        }
        for c in columns.iter_mut() {
            for v in c.1.iter_mut() {
                // 1 pm / 1 µK: keeps the CSV short
                *v = (*v * 1e6).round() / 1e6;
            }
        }
        Columns { columns }
    }
}

/// The effector poses of a regular `n × n × n` grid over ±`half_mm` (serpentine in x, then y,
/// layer by layer in z), mm.
pub fn grid_poses_mm(n: usize, half_mm: f64) -> Vec<[f64; 3]> {
    let v = |k: usize| -half_mm + 2.0 * half_mm * k as f64 / (n - 1).max(1) as f64;
    let mut out = Vec::with_capacity(n * n * n);
    for iz in 0..n {
        for iy in 0..n {
            let row = iz * n + iy;
            for k in 0..n {
                let ix = if row.is_multiple_of(2) { k } else { n - 1 - k };
                out.push([v(ix), v(iy), v(iz)]);
            }
        }
    }
    out
}

/// `count` effector poses drawn uniformly in the cube ±`half_mm` from `seed`, mm.
pub fn random_poses_mm(count: usize, half_mm: f64, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..count)
        .map(|_| std::array::from_fn(|_| rng.gen_range(-half_mm..half_mm)))
        .collect()
}

/// Motor coordinates (µm) of effector poses (mm) by the nominal inverse geometric model — what
/// the robot's controller commands for them.
pub fn motor_poses_um(poses_mm: &[[f64; 3]]) -> Vec<Vec<f64>> {
    let g = DeltaGeometry::nominal();
    poses_mm
        .iter()
        .map(|&p| {
            g.inverse_mm(p)
                .iter()
                .map(|m| (m * 1e6).round() / 1e3)
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nominal_inverse_and_forward_agree() {
        let g = DeltaGeometry::nominal();
        assert!(g.inverse_mm([0.0; 3]).iter().all(|m| m.abs() < 1e-12));
        // moving up by z moves every carriage up by z
        let m = g.inverse_mm([0.0, 0.0, 2.0]);
        assert!(m.iter().all(|v| (v - 2.0).abs() < 1e-12));
        for p in random_poses_mm(20, 5.0, 1) {
            let back = g.forward_mm(g.inverse_mm(p), [0.0; 3]);
            for a in 0..3 {
                assert!((back[a] - p[a]).abs() < 1e-11, "{p:?} → {back:?}");
            }
        }
    }

    #[test]
    fn arms_lengthen_with_temperature() {
        let g = DeltaGeometry::nominal();
        let warm = g.at_temperatures(&PartTemperatures {
            arm_k: [1.0; 3],
            ..Default::default()
        });
        // at the origin, dm/dL = L / Z0 = 60 / 48.73; ΔL = 60 mm × 8.6 ppm = 0.516 µm
        let dm_um = warm.inverse_mm([0.0; 3])[0] * 1e3;
        let z0 = (60.0f64 * 60.0 - 35.0 * 35.0).sqrt();
        assert!((dm_um - 0.516 * 60.0 / z0).abs() < 1e-4, "{dm_um}");
    }

    #[test]
    fn recording_layout_and_workspace() {
        let cfg = DeltaConfig::paper001(1);
        let twin = DeltaTwin::new(cfg, 86_400.0, 1);
        let poses = motor_poses_um(&grid_poses_mm(3, 4.0));
        let traj = Trajectory {
            dwells: poses
                .iter()
                .map(|p| super::super::Dwell {
                    cmd_um: p.clone(),
                    dwell_s: 5.0,
                })
                .collect(),
        };
        let rec = twin.simulate(&traj, 0.0, 1);
        let names: Vec<&str> = rec.columns.iter().map(|c| c.0.as_str()).collect();
        assert_eq!(names.len(), 1 + 3 + 3 + 10);
        assert_eq!(names[1], "cmd_m1");
        assert!(names.contains(&"temp_air_z") && !names.contains(&"temp_effector"));
        // measured motor coordinates are the commands within tens of µm (tolerances)
        let d: f64 = rec
            .get("meas_m1")
            .unwrap()
            .iter()
            .zip(rec.get("cmd_m1").unwrap())
            .map(|(m, c)| (m - c).abs())
            .fold(0.0, f64::max);
        assert!(d > 1.0 && d < 200.0, "max |meas − cmd| {d} µm");
    }
}
