//! The campaign's recording, written as it goes in the shared layout (`../shared/README.md`):
//! `t` (s, plan time), `cmd_<axis>` (the command the stage controller received, µm),
//! `meas_<axis>` (the reference instrument, µm), `temp_<name>` (°C, as the compensator read
//! them) and the compensator's auxiliary inputs (`pressure` hPa, `force` N) in its input order —
//! nothing else, so that a model's Temp(i)/Aux(i) are the i-th such column, as the device sees
//! them.
//!
//! Rows are flushed at every step; the campaign's state remembers the file's length at the last
//! completed step, and a resumed campaign cuts the file back to it (a step cut short by a crash or
//! Ctrl-C is redone whole).

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Column names of a campaign recording.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Layout {
    /// Axis names (`x`, `y`, `z`).
    pub axes: Vec<String>,
    /// Temperature channel names, without `temp_`, in the compensator's channel order.
    pub temps: Vec<String>,
    /// Auxiliary channel names, in the compensator's aux-input order.
    pub aux: Vec<String>,
}

impl Layout {
    /// The header row (no line end).
    pub fn header(&self) -> String {
        let mut h = vec!["t".to_string()];
        h.extend(self.axes.iter().map(|a| format!("cmd_{a}")));
        h.extend(self.axes.iter().map(|a| format!("meas_{a}")));
        h.extend(self.temps.iter().map(|n| format!("temp_{n}")));
        h.extend(self.aux.iter().cloned());
        h.join(",")
    }
}

/// Errors of the recorder.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RecorderError {
    /// The file could not be written.
    #[error("recording {path}: {cause}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        cause: std::io::Error,
    },
    /// A resumed recording does not start with this campaign's header.
    #[error("recording {path}: its header `{found}` is not this campaign's `{expected}`")]
    Header {
        /// The file.
        path: PathBuf,
        /// What the file has.
        found: String,
        /// What the campaign writes.
        expected: String,
    },
}

/// One row.
#[derive(Debug, Clone, PartialEq)]
pub struct Row<'a> {
    /// Plan time, s.
    pub t_s: f64,
    /// Command per axis, µm.
    pub cmd_um: &'a [f64],
    /// Reference per axis, µm.
    pub meas_um: &'a [f64],
    /// Temperatures as the compensator holds them (f32), °C.
    pub temps_c: &'a [f32],
    /// Aux inputs as the compensator holds them.
    pub aux: &'a [f32],
}

/// Writes the recording.
pub struct Recorder {
    path: PathBuf,
    w: BufWriter<File>,
    bytes: u64,
    line: String,
}

impl Recorder {
    fn io(path: &Path) -> impl Fn(std::io::Error) -> RecorderError + '_ {
        move |cause| RecorderError::Io {
            path: path.to_path_buf(),
            cause,
        }
    }

    /// A new recording at `path` (replaced if it exists).
    pub fn create(path: &Path, layout: &Layout) -> Result<Self, RecorderError> {
        let f = File::create(path).map_err(Self::io(path))?;
        let mut r = Self {
            path: path.to_path_buf(),
            w: BufWriter::new(f),
            bytes: 0,
            line: String::new(),
        };
        let h = format!("{}\n", layout.header());
        r.w.write_all(h.as_bytes()).map_err(Self::io(path))?;
        r.bytes = h.len() as u64;
        r.commit()?;
        Ok(r)
    }

    /// Continue the recording at `path`, cut back to `committed` bytes (the end of the last
    /// completed step); its header must be `layout`'s.
    pub fn resume(path: &Path, layout: &Layout, committed: u64) -> Result<Self, RecorderError> {
        let text = std::fs::read(path).map_err(Self::io(path))?;
        let first = text
            .split(|&b| b == b'\n')
            .next()
            .map(|l| String::from_utf8_lossy(l).into_owned())
            .unwrap_or_default();
        if first != layout.header() {
            return Err(RecorderError::Header {
                path: path.to_path_buf(),
                found: first,
                expected: layout.header(),
            });
        }
        let f = OpenOptions::new()
            .write(true)
            .open(path)
            .map_err(Self::io(path))?;
        let keep = committed.min(text.len() as u64);
        f.set_len(keep).map_err(Self::io(path))?;
        let mut f = f;
        use std::io::Seek;
        f.seek(std::io::SeekFrom::End(0)).map_err(Self::io(path))?;
        Ok(Self {
            path: path.to_path_buf(),
            w: BufWriter::new(f),
            bytes: keep,
            line: String::new(),
        })
    }

    /// Append a row (buffered until [`Self::commit`]).
    pub fn row(&mut self, r: &Row<'_>) -> Result<(), RecorderError> {
        use std::fmt::Write as _;
        let l = &mut self.line;
        l.clear();
        let _ = write!(l, "{:.3}", r.t_s);
        for v in r.cmd_um.iter().chain(r.meas_um) {
            let _ = write!(l, ",{v:.6}");
        }
        // f32 as the device holds it: the shortest decimal that reads back to the same f32
        for v in r.temps_c.iter().chain(r.aux) {
            let _ = write!(l, ",{v}");
        }
        l.push('\n');
        self.w
            .write_all(l.as_bytes())
            .map_err(Self::io(&self.path))?;
        self.bytes += l.len() as u64;
        Ok(())
    }

    /// Flush to the file; returns its length (what a resume cuts back to).
    pub fn commit(&mut self) -> Result<u64, RecorderError> {
        self.w.flush().map_err(Self::io(&self.path))?;
        Ok(self.bytes)
    }

    /// Flush and ask the OS to put it on disk (at phase ends and before exiting).
    pub fn sync(&mut self) -> Result<u64, RecorderError> {
        let n = self.commit()?;
        self.w.get_ref().sync_data().map_err(Self::io(&self.path))?;
        Ok(n)
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::recording::Recording;

    #[test]
    fn rows_read_back_and_a_resume_cuts_the_unfinished_step() {
        let dir = std::env::temp_dir().join(format!("nanocal-rec-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("r.csv");
        let layout = Layout {
            axes: vec!["x".into()],
            temps: vec!["cs0".into()],
            aux: vec!["pressure".into()],
        };
        let mut r = Recorder::create(&p, &layout).unwrap();
        let t = 21.8125f32;
        r.row(&Row {
            t_s: 0.0,
            cmd_um: &[30.0],
            meas_um: &[30.000123],
            temps_c: &[t],
            aux: &[1013.25],
        })
        .unwrap();
        let kept = r.commit().unwrap();
        r.row(&Row {
            t_s: 1.0,
            cmd_um: &[60.0],
            meas_um: &[60.0],
            temps_c: &[f32::NAN],
            aux: &[1013.25],
        })
        .unwrap();
        r.commit().unwrap();
        drop(r);
        let rec = Recording::read_path(&p).unwrap();
        assert_eq!(rec.rows(), 2);
        assert_eq!(rec.column("temp_cs0").unwrap()[0] as f32, t);
        assert!(rec.column("temp_cs0").unwrap()[1].is_nan());
        let mut r = Recorder::resume(&p, &layout, kept).unwrap();
        r.commit().unwrap();
        assert_eq!(Recording::read_path(&p).unwrap().rows(), 1);
        let other = Layout {
            temps: vec![],
            ..layout
        };
        assert!(matches!(
            Recorder::resume(&p, &other, kept),
            Err(RecorderError::Header { .. })
        ));
        std::fs::remove_dir_all(&dir).ok();
    }
}
