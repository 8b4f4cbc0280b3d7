//! `nanocal import`: a PI data-recorder file (GCSArray text, or a saved `DRR?` reply) to a
//! recording in the shared layout.

use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::Args;

use crate::data::gcsarray::GcsArray;
use crate::data::recording::Recording;

/// Import a PI data-recorder file (GCSArray text as PI's software and PIPython's
/// `pitools.savegcsarray` write it, or the text of a `DRR?` reply as PIPython's `qDRR` reads
/// it) as a recording: each `--map COLUMN=TABLE` puts a recorded table into a column of the
/// shared layout, and you name which table is the reference measurement (`meas_<axis>`).
#[derive(Args, Debug)]
pub struct ImportArgs {
    /// The data-recorder file.
    pub file: PathBuf,
    /// Output recording (CSV, shared layout).
    #[arg(short, long)]
    pub output: PathBuf,
    /// `COLUMN=TABLE`: the recording column (`cmd_<axis>`, `meas_<axis>` — the reference —,
    /// `temp_<name>`, an aux name, or `t`) and the table that fills it (1-based number, or the
    /// table's `NAME<i>` from the header). Repeat per column.
    #[arg(long = "map", value_name = "COLUMN=TABLE", required = true)]
    pub map: Vec<String>,
    /// Seconds between rows when the header has no `SAMPLE_TIME` and no table is mapped to `t`.
    #[arg(long)]
    pub sample_time_s: Option<f64>,
    /// Multiply `cmd_*` and `meas_*` values by this to get µm (e.g. 1000 for a controller in mm).
    #[arg(long, default_value_t = 1.0)]
    pub to_um: f64,
}

/// Runs `nanocal import`.
pub fn run(args: ImportArgs) -> anyhow::Result<()> {
    let g = GcsArray::read_path(&args.file)
        .with_context(|| format!("reading {}", args.file.display()))?;
    let rec = to_recording(&g, &args.map, args.sample_time_s, args.to_um)
        .with_context(|| format!("{}", args.file.display()))?;
    rec.write_path(&args.output)
        .with_context(|| format!("writing {}", args.output.display()))?;
    println!(
        "wrote {} ({} rows, columns {})",
        args.output.display(),
        rec.rows(),
        rec.names().join(", ")
    );
    Ok(())
}

/// The recording the mapping makes of a data-recorder file.
pub fn to_recording(
    g: &GcsArray,
    map: &[String],
    sample_time_s: Option<f64>,
    to_um: f64,
) -> anyhow::Result<Recording> {
    let tables: Vec<String> = (0..g.tables.len())
        .map(|i| match g.name(i) {
            Some(n) => format!("{} ({n})", i + 1),
            None => format!("{}", i + 1),
        })
        .collect();
    let mut cols: Vec<(String, Vec<f64>)> = Vec::new();
    for m in map {
        let Some((col, table)) = m.split_once('=') else {
            bail!("--map `{m}`: expected COLUMN=TABLE, e.g. meas_x=2");
        };
        let (col, table) = (col.trim(), table.trim());
        if col.is_empty() || col.contains(',') {
            bail!("--map `{m}`: `{col}` is not a column name");
        }
        let Some(i) = g.table_index(table) else {
            bail!(
                "--map `{m}`: no table `{table}`; the file has tables {}",
                tables.join(", ")
            );
        };
        if cols.iter().any(|(c, _)| c == col) {
            bail!("--map: column `{col}` is mapped twice");
        }
        let scale = if col.starts_with("cmd_") || col.starts_with("meas_") {
            to_um
        } else {
            1.0
        };
        cols.push((
            col.to_string(),
            g.tables[i].iter().map(|v| v * scale).collect(),
        ));
    }
    let axes: Vec<&str> = cols
        .iter()
        .filter_map(|(c, _)| c.strip_prefix("cmd_"))
        .collect();
    if axes.is_empty() {
        bail!("--map: name the commanded table of at least one axis, e.g. cmd_x=1");
    }
    for a in &axes {
        if !cols.iter().any(|(c, _)| c == &format!("meas_{a}")) {
            bail!(
                "--map: name the table that is the reference measurement of axis {a}: meas_{a}=TABLE (tables: {})",
                tables.join(", ")
            );
        }
    }
    if !cols.iter().any(|(c, _)| c == "t") {
        let dt = match (g.sample_time_s(), sample_time_s) {
            (_, Some(dt)) => dt,
            (Some(dt), None) => dt,
            (None, None) => bail!(
                "the header has no SAMPLE_TIME: give --sample-time-s, or map a recorded time table with --map t=TABLE"
            ),
        };
        if !(dt > 0.0 && dt.is_finite()) {
            bail!("sample time must be a positive number of seconds, found {dt}");
        }
        cols.insert(
            0,
            ("t".into(), (0..g.rows()).map(|i| i as f64 * dt).collect()),
        );
    }
    Ok(Recording::from_columns(cols)?)
}
