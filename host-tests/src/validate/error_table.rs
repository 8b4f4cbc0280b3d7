//! A fitted correction as a per-axis, bidirectional error table, for controllers that take
//! tables instead of a model.
//!
//! Sign convention (written in the file's header): **error = reference − commanded**. The
//! stage commanded to `position_um` (without correction) goes to `position_um + error`, as the
//! model says: with the model's command map `q(x)` (the command that reaches `x`), the row at
//! commanded position `c` holds `x − c` where `q(x) = c`, solved by Newton's method on the f64
//! reference evaluation. Forward is an approach from below (increasing command, direction +1),
//! backward from above (−1); they differ when the model has direction or hysteresis terms.
//! Every other input is held at a stated value: the other axes, the temperatures (the lag
//! filters in steady state: lagged = temperature) and aux channels.
//!
//! File layout (`#` comment lines, then a CSV header and one row per position):
//!
//! ```text
//! # nanocal bidirectional error table
//! # sign convention: error = reference − commanded, µm …
//! # model id 0x00030001, axis 1 of 1, …
//! # temperatures (°C, model Temp index order): 22.5
//! position_um,forward_error_um,backward_error_um
//! 0.000000000,0.012345678,0.012345678
//! ```

use nanocal_model::{Input, Model, SlowInputs, MAX_AXES};

/// Errors building or reading a table.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum ErrorTableError {
    /// The axis is not in the model.
    #[error("axis {axis} is not in the model (it has {axes} axes; axes are numbered from 1)")]
    NoAxis {
        /// 1-based axis asked for.
        axis: usize,
        /// Axes of the model.
        axes: usize,
    },
    /// A list of held values has the wrong length.
    #[error("{what}: {found} values given, the model has {expected}")]
    WrongCount {
        /// Which values.
        what: &'static str,
        /// Expected.
        expected: usize,
        /// Given.
        found: usize,
    },
    /// The step is not a positive number.
    #[error("step must be a positive number of µm, found {0}")]
    BadStep(f64),
    /// Newton's method did not converge (the model is not invertible there).
    #[error("the model's command map is not invertible near {0} µm")]
    NotInvertible(f64),
    /// A table line could not be read.
    #[error("line {line}: {problem}")]
    BadLine {
        /// 1-based line.
        line: usize,
        /// What is wrong.
        problem: String,
    },
}

/// Where the other inputs are held.
#[derive(Debug, Clone, PartialEq)]
pub struct Conditions {
    /// Every axis's position, µm (the tabulated axis's entry is ignored).
    pub axes_um: Vec<f64>,
    /// Temperatures by model Temp index, °C.
    pub temps_c: Vec<f64>,
    /// Aux channels by model Aux index.
    pub aux: Vec<f64>,
}

impl Conditions {
    /// The middle of the training envelope of every input.
    pub fn envelope_middle(model: &Model) -> Self {
        let mid = |i: Input| {
            let (lo, hi) = model.envelope(i);
            0.5 * (lo + hi)
        };
        Conditions {
            axes_um: (0..model.axes())
                .map(|a| mid(Input::Axis(a as u8)))
                .collect(),
            temps_c: (0..model.temps())
                .map(|t| mid(Input::Temp(t as u8)))
                .collect(),
            aux: (0..model.aux()).map(|n| mid(Input::Aux(n as u8))).collect(),
        }
    }

    fn check(&self, model: &Model) -> Result<(), ErrorTableError> {
        for (what, expected, found) in [
            ("axis positions", model.axes(), self.axes_um.len()),
            ("temperatures", model.temps(), self.temps_c.len()),
            ("aux values", model.aux(), self.aux.len()),
        ] {
            if expected != found {
                return Err(ErrorTableError::WrongCount {
                    what,
                    expected,
                    found,
                });
            }
        }
        Ok(())
    }

    /// The slow inputs (lag filters in steady state).
    pub fn slow(&self, model: &Model) -> SlowInputs {
        let mut s = SlowInputs::default();
        for (t, v) in self.temps_c.iter().enumerate() {
            s.temps_c[t] = *v;
        }
        for (n, v) in self.aux.iter().enumerate() {
            s.aux[n] = *v;
        }
        for (k, lag) in model.lags().iter().enumerate() {
            s.lagged_c[k] = s.temps_c[lag.sensor as usize];
        }
        s
    }
}

/// One row: commanded position and the error in each direction, µm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Row {
    /// Commanded position, µm.
    pub position_um: f64,
    /// Reference − commanded, approached from below.
    pub forward_error_um: f64,
    /// Reference − commanded, approached from above.
    pub backward_error_um: f64,
}

/// The position `x` on `axis` that command `c` reaches: `q_axis(x) = c`, Newton from `x = c`.
pub fn reached_um(
    model: &Model,
    axis: usize,
    c: f64,
    dir: i8,
    at: &Conditions,
    slow: &SlowInputs,
) -> Result<f64, ErrorTableError> {
    let mut x = [0.0; MAX_AXES];
    for (a, v) in at.axes_um.iter().enumerate() {
        x[a] = *v;
    }
    let mut d = [0i8; MAX_AXES];
    d[axis] = dir;
    let q = |xa: f64| {
        let mut xx = x;
        xx[axis] = xa;
        model.eval_f64(&xx, &d, slow)[axis]
    };
    let mut xa = c;
    for _ in 0..50 {
        let g = q(xa) - c;
        if g.abs() < 1e-10 {
            return Ok(xa);
        }
        let h = 1e-3;
        let slope = (q(xa + h) - q(xa - h)) / (2.0 * h);
        if !(slope.is_finite() && slope.abs() > 1e-6) {
            break;
        }
        xa -= g / slope;
    }
    Err(ErrorTableError::NotInvertible(c))
}

/// The table of `axis` (0-based) from `from_um` to `to_um` every `step_um` (the last point is
/// `to_um`).
pub fn table(
    model: &Model,
    axis: usize,
    from_um: f64,
    to_um: f64,
    step_um: f64,
    at: &Conditions,
) -> Result<Vec<Row>, ErrorTableError> {
    if axis >= model.axes() {
        return Err(ErrorTableError::NoAxis {
            axis: axis + 1,
            axes: model.axes(),
        });
    }
    at.check(model)?;
    if !(step_um > 0.0 && step_um.is_finite()) {
        return Err(ErrorTableError::BadStep(step_um));
    }
    let slow = at.slow(model);
    let n = ((to_um - from_um) / step_um).ceil().max(0.0) as usize;
    (0..=n)
        .map(|i| {
            let c = (from_um + i as f64 * step_um).min(to_um);
            Ok(Row {
                position_um: c,
                forward_error_um: reached_um(model, axis, c, 1, at, &slow)? - c,
                backward_error_um: reached_um(model, axis, c, -1, at, &slow)? - c,
            })
        })
        .collect()
}

/// The CSV text (module doc), with the conditions and the model stated in the header.
pub fn to_csv(model: &Model, axis: usize, at: &Conditions, rows: &[Row]) -> String {
    use std::fmt::Write;
    let list = |v: &[f64]| {
        if v.is_empty() {
            "none".to_string()
        } else {
            v.iter()
                .map(|x| format!("{x}"))
                .collect::<Vec<_>>()
                .join(", ")
        }
    };
    let mut s = String::new();
    let _ = writeln!(s, "# nanocal bidirectional error table");
    let _ = writeln!(
        s,
        "# sign convention: error = reference − commanded, µm: the stage commanded to position_um without correction goes to position_um + error"
    );
    let _ = writeln!(
        s,
        "# forward: approached from below (increasing command); backward: approached from above"
    );
    let _ = writeln!(
        s,
        "# model id 0x{:08x}, axis {} of {}",
        model.id(),
        axis + 1,
        model.axes()
    );
    let _ = writeln!(
        s,
        "# other axes held at (µm, model axis order): {}",
        list(&at.axes_um)
    );
    let _ = writeln!(
        s,
        "# temperatures (°C, model Temp index order; lag filters in steady state): {}",
        list(&at.temps_c)
    );
    let _ = writeln!(s, "# aux (model Aux index order): {}", list(&at.aux));
    let _ = writeln!(s, "position_um,forward_error_um,backward_error_um");
    for r in rows {
        let _ = writeln!(
            s,
            "{:.9},{:.9},{:.9}",
            r.position_um, r.forward_error_um, r.backward_error_um
        );
    }
    s
}

/// Reads the rows of a table written by [`to_csv`] (comment lines skipped).
pub fn parse_csv(text: &str) -> Result<Vec<Row>, ErrorTableError> {
    let mut rows = Vec::new();
    let mut header = false;
    for (k, l) in text.lines().enumerate() {
        let line = k + 1;
        if l.starts_with('#') || l.trim().is_empty() {
            continue;
        }
        if !header {
            if l.trim() != "position_um,forward_error_um,backward_error_um" {
                return Err(ErrorTableError::BadLine {
                    line,
                    problem: format!(
                        "expected the header `position_um,forward_error_um,backward_error_um`, found `{l}`"
                    ),
                });
            }
            header = true;
            continue;
        }
        let v: Result<Vec<f64>, _> = l.split(',').map(|f| f.trim().parse::<f64>()).collect();
        match v {
            Ok(v) if v.len() == 3 => rows.push(Row {
                position_um: v[0],
                forward_error_um: v[1],
                backward_error_um: v[2],
            }),
            _ => {
                return Err(ErrorTableError::BadLine {
                    line,
                    problem: format!("expected three numbers, found `{l}`"),
                })
            }
        }
    }
    Ok(rows)
}
