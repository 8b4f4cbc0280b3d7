//! What an effect may look at while the twin produces it: a leaf the twin fills and the effects
//! read, so the effects need not import the twin (which imports the effects).

/// Everything an effect may look at while the twin produces it.
#[derive(Debug)]
pub struct SimContext<'a> {
    /// Number of axes of the simulated stage (1–3).
    pub axes: usize,
    /// Travel per axis (min, max), µm.
    pub travel_um: &'a [(f64, f64)],
    /// Thermal drift per axis and sensor, µm/°C (relative to `temp_ref_c`).
    pub thermal_um_per_c: &'a [Vec<f64>],
    /// Reference temperature of the thermal drift, °C.
    pub temp_ref_c: f64,
    /// Mean barometric pressure of the room, hPa.
    pub pressure_mean_hpa: f64,
    /// Time since the start of this recording, s.
    pub t_s: Vec<f64>,
    /// Absolute time (since the room's origin), s.
    pub t_abs_s: Vec<f64>,
    /// Commanded position per axis, µm.
    pub cmd_um: Vec<Vec<f64>>,
    /// Scaled command per axis, [-1, 1].
    pub u: Vec<Vec<f64>>,
    /// Direction of the last move per axis (+1 forward, -1 backward; +1 before the first move).
    pub dir: Vec<Vec<f64>>,
    /// Moves per axis: (first sample index at the new pose, step in µm).
    pub steps: Vec<Vec<(usize, f64)>>,
    /// True (noise-free) temperature of each sensor's spot, °C.
    pub spot_c: Vec<Vec<f64>>,
    /// True barometric pressure, hPa.
    pub pressure_hpa: Vec<f64>,
    /// True stage position per axis, µm (filled before interferometer effects run).
    pub pos_um: Vec<Vec<f64>>,
    /// A seed for effects that draw random events.
    pub seed: u64,
}
