//! `nanocal stepwise`: MATLAB-semantics stepwise regression on the columns of a CSV file.

use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::Args;

use crate::data::recording::Recording;
use crate::numerics::linalg::{compress_parts, merge_parts, Compressed, CompressedPart};
use crate::numerics::stepwise::{stepwise_compressed, Action, StepwiseOptions, StepwiseResult};

/// Stepwise linear regression with MATLAB `stepwisefit` semantics: every numeric column other
/// than the response (and those listed in `--exclude`) is a candidate term; the intercept is
/// always in the model.
#[derive(Args, Debug)]
pub struct StepwiseArgs {
    /// CSV file (header row, one row per sample).
    pub file: PathBuf,
    /// Name of the response column.
    #[arg(long)]
    pub response: String,
    /// p-value to enter a term (MATLAB default 0.05).
    #[arg(long)]
    pub penter: Option<f64>,
    /// p-value to remove a term (default max(penter, 0.10)).
    #[arg(long)]
    pub premove: Option<f64>,
    /// Maximum number of steps.
    #[arg(long)]
    pub maxiter: Option<usize>,
    /// Columns in the initial model (names, comma separated).
    #[arg(long, value_delimiter = ',')]
    pub inmodel: Vec<String>,
    /// Columns whose status never changes (names, comma separated).
    #[arg(long, value_delimiter = ',')]
    pub keep: Vec<String>,
    /// Columns that are not candidates (names, comma separated), e.g. `t`.
    #[arg(long, value_delimiter = ',')]
    pub exclude: Vec<String>,
    /// Write the full result (b, se, pval, inmodel, history, ...) as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Held-out accuracy over this many contiguous blocks of rows in file order (rows are
    /// assumed in time order: a block is "later data", not random rows); 0: skip.
    #[arg(long, default_value_t = 5)]
    pub blocks: usize,
}

/// Runs `nanocal stepwise`.
pub fn run(args: StepwiseArgs) -> anyhow::Result<()> {
    let bar = crate::cli::validate::spinner(format!("reading {}", args.file.display()));
    let rec = Recording::read_path(&args.file)?;
    bar.finish_and_clear();
    let y = rec.require(&args.response)?;
    for n in &args.exclude {
        rec.require(n).context("--exclude")?;
    }
    let names: Vec<String> = rec
        .names()
        .iter()
        .filter(|n| **n != args.response && !args.exclude.contains(n))
        .cloned()
        .collect();
    if names.is_empty() {
        bail!(
            "{}: expected at least one candidate column besides `{}`",
            args.file.display(),
            args.response
        );
    }
    let x: Vec<&[f64]> = names
        .iter()
        .map(|n| rec.column(n).expect("listed"))
        .collect();
    let index_of = |what: &str, list: &[String]| -> anyhow::Result<Vec<usize>> {
        list.iter()
            .map(|n| {
                names.iter().position(|c| c == n).with_context(|| {
                    format!(
                        "--{what}: column `{n}` is not a candidate; candidates: {}",
                        names.join(", ")
                    )
                })
            })
            .collect()
    };
    let opts = StepwiseOptions {
        penter: args.penter,
        premove: args.premove,
        maxiter: args.maxiter,
        inmodel: index_of("inmodel", &args.inmodel)?,
        keep: index_of("keep", &args.keep)?,
        threads: None,
    };
    let bar = crate::cli::validate::spinner(format!(
        "stepwise over {} candidates, {} rows",
        x.len(),
        y.len()
    ));
    opts.thresholds()?;
    let blocks = Blocks::compress(&x, y, args.blocks, opts.thread_count())?;
    let full = blocks.merged(None);
    let res = stepwise_compressed(full.clone(), &opts)?;
    bar.finish_and_clear();
    print!("{}", table(&names, &res, &opts));
    let trust = Trust::of(&names, &x, y, &res, &opts, &blocks, &full)?;
    print!("{}", trust.text(&args.response));
    if let Some(path) = &args.json {
        let mut json = to_json(&names, &args.response, &res);
        json["trust"] = trust.json();
        std::fs::write(path, serde_json::to_string_pretty(&json)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

fn listed(names: &[String], mask: &[bool]) -> String {
    let v: Vec<&str> = names
        .iter()
        .zip(mask)
        .filter(|(_, m)| **m)
        .map(|(n, _)| n.as_str())
        .collect();
    if v.is_empty() {
        "none".into()
    } else {
        v.join(" ")
    }
}

/// The MATLAB-like report: steps, then the coefficient table and the model statistics.
#[allow(clippy::needless_range_loop)]
pub fn table(names: &[String], res: &StepwiseResult, opts: &StepwiseOptions) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let mut init = vec![false; names.len()];
    opts.inmodel.iter().for_each(|&i| init[i] = true);
    let _ = writeln!(s, "Initial columns included: {}", listed(names, &init));
    for (k, st) in res.history.iter().enumerate() {
        let (what, j) = match st.action {
            Action::Added(j) => ("added", j),
            Action::Removed(j) => ("removed", j),
        };
        let _ = writeln!(
            s,
            "Step {}, {what} column {} ({}), p={:.6e}",
            k + 1,
            j + 1,
            names[j],
            st.p
        );
    }
    let _ = writeln!(s, "Final columns included: {}", listed(names, &res.inmodel));
    let w = names.iter().map(|n| n.len()).max().unwrap_or(6).max(6);
    let _ = writeln!(
        s,
        "{:>w$} {:>14} {:>14} {:>6} {:>14}",
        "", "Coeff", "Std.Err.", "Status", "P"
    );
    for j in 0..names.len() {
        let _ = writeln!(
            s,
            "{:>w$} {:>14.6e} {:>14.6e} {:>6} {:>14.6e}",
            names[j],
            res.b[j],
            res.se[j],
            if res.inmodel[j] { "In" } else { "Out" },
            res.pval[j]
        );
    }
    let _ = writeln!(
        s,
        "intercept {:.6}  RMSE {:.6}  R² {:.6}  adjusted R² {:.6}  F {:.6} (p {:.4e})  df0 {}  dfe {}  n {}",
        res.intercept,
        res.rmse,
        res.r_squared,
        res.r_squared_adjusted,
        res.fstat,
        res.fpval,
        res.df0,
        res.dfe,
        res.rows_used
    );
    s
}

fn num(v: f64) -> serde_json::Value {
    if v.is_finite() {
        serde_json::json!(v)
    } else {
        serde_json::Value::Null
    }
}

/// The result as JSON (NaN/∞ as null; column indices 1-based as in the Octave oracle).
pub fn to_json(names: &[String], response: &str, res: &StepwiseResult) -> serde_json::Value {
    let nums = |v: &[f64]| serde_json::Value::Array(v.iter().map(|&x| num(x)).collect());
    let history: Vec<serde_json::Value> = res
        .history
        .iter()
        .enumerate()
        .map(|(k, st)| {
            let (act, j) = match st.action {
                Action::Added(j) => ("add", j),
                Action::Removed(j) => ("remove", j),
            };
            serde_json::json!({"step": k + 1, "action": act, "idx": j + 1, "name": names[j], "p": num(st.p),
                "rmse": num(st.rmse), "df0": st.df0,
                "inmodel_idx": (0..names.len()).filter(|&i| st.inmodel[i]).map(|i| i + 1).collect::<Vec<_>>()})
        })
        .collect();
    serde_json::json!({
        "header": names, "response": response, "n_used": res.rows_used,
        "inmodel": res.inmodel,
        "selected": names.iter().zip(&res.inmodel).filter(|(_, m)| **m).map(|(n, _)| n.clone()).collect::<Vec<_>>(),
        "selected_idx": (0..names.len()).filter(|&i| res.inmodel[i]).map(|i| i + 1).collect::<Vec<_>>(),
        "b": nums(&res.b), "se": nums(&res.se), "pval": nums(&res.pval), "tstat": nums(&res.tstat),
        "intercept": num(res.intercept), "rmse": num(res.rmse), "r2": num(res.r_squared), "r2_adjusted": num(res.r_squared_adjusted),
        "fstat": num(res.fstat), "model_pval": num(res.fpval), "dfe": res.dfe, "df0": res.df0,
        "SStotal": num(res.ss_total), "SSresid": num(res.ss_resid),
        "nextstep": res.nextstep.map_or(0, |j| j + 1), "history": history,
    })
}

/// What the stepwise fit knows about itself: the 95 % prediction interval over the data, the
/// variance inflation of the columns in the final model, held-out accuracy by blocks of rows.
pub struct Trust {
    /// Half-width of the 95 % prediction interval at the rows: (min, median, max).
    pub pi95: (f64, f64, f64),
    /// Why there is no interval, if there is none.
    pub pi_error: Option<String>,
    /// VIF of the final model's columns.
    pub vif: Vec<crate::numerics::uncertainty::Vif>,
    /// Held-out accuracy (stepwise rerun without each block), if asked.
    pub held_out: Option<crate::numerics::uncertainty::HeldOut>,
    /// Why there is no held-out accuracy although it was asked for (too few rows, …).
    pub held_out_error: Option<String>,
}

impl Trust {
    /// Computes it for the final model of `res`, fitted on `blocks` (held-out fits leave one
    /// block's compression out of the merge: no further pass over the data); `full` is the
    /// merge of every block, from whose triangle come the prediction interval's factor and the
    /// VIFs (no pass over the data either; only the leverage at each row reads the rows).
    pub fn of(
        names: &[String],
        x: &[&[f64]],
        y: &[f64],
        res: &StepwiseResult,
        opts: &StepwiseOptions,
        blocks: &Blocks,
        full: &Compressed,
    ) -> anyhow::Result<Self> {
        use crate::numerics::uncertainty::{
            variance_inflation_compressed, HeldOut, HeldOutSum, PredictionBand,
        };
        let sel: Vec<usize> = (0..names.len()).filter(|&j| res.inmodel[j]).collect();
        // the triangle's columns: 0 is the intercept, candidate j is j + 1
        let rcols: Vec<usize> = sel.iter().map(|&j| j + 1).collect();
        let constant: Vec<bool> = sel.iter().map(|&j| full.constant[j]).collect();
        // rows the fit used (no NaN in y or any candidate)
        let used = &blocks.used;
        let refs: Vec<&[f64]> = sel.iter().map(|&j| x[j]).collect();
        let band =
            PredictionBand::from_compressed(&full.r, full.rows, &rcols, &constant, res.ss_resid);
        let held_out = |ranges: &[(usize, usize)]| -> anyhow::Result<HeldOut> {
            // the held-out errors summed as they come, a tile of rows at a time into one
            // reused buffer: the same sums in the same order as a vector per block, without
            // the fresh memory (its page faults were most of this single-threaded tail)
            const TILE: usize = 1024;
            let mut sum = HeldOutSum::default();
            let mut prediction = [0.0f64; TILE];
            for (b, &(start, end)) in ranges.iter().enumerate() {
                let fold = stepwise_compressed(blocks.merged(Some(b)), opts)?;
                let terms: Vec<(&[f64], f64)> = x
                    .iter()
                    .enumerate()
                    .filter(|(j, _)| fold.inmodel[*j])
                    .map(|(j, c)| (*c, fold.b[j]))
                    .collect();
                let rows = &used[start..end];
                // the used rows ascend: a block without a NaN row is one range of the columns
                let contiguous =
                    rows.last().zip(rows.first()).map(|(l, f)| l - f + 1) == Some(rows.len());
                let mut block = sum.start_block();
                for tile in rows.chunks(TILE) {
                    let p = &mut prediction[..tile.len()];
                    p.fill(0.0);
                    // the fold's prediction at each held-out row, summed as `predict` sums
                    for &(c, bj) in &terms {
                        if contiguous {
                            let from = tile[0];
                            for (s, &v) in p.iter_mut().zip(&c[from..from + tile.len()]) {
                                *s += v * bj;
                            }
                        } else {
                            for (s, &i) in p.iter_mut().zip(tile) {
                                *s += c[i] * bj;
                            }
                        }
                    }
                    for (s, &i) in p.iter().zip(tile) {
                        block.add(y[i] - (fold.intercept + s));
                    }
                }
                block.finish();
            }
            Ok(sum.finish())
        };
        let held_out = || match &blocks.ranges {
            None => (None, None),
            Some(Err(e)) => (None, Some(e.clone())),
            Some(Ok(ranges)) => match held_out(ranges) {
                Ok(h) => (Some(h), None),
                Err(e) => (None, Some(format!("{e:#}"))),
            },
        };
        // The leverage at each row (split across the threads of the compression) and the
        // held-out refits with their predictions run side by side: one after the other, the
        // refits (≈ 10 ms on one core) left the second core idle.
        let ((pi95, pi_error), (held_out, held_out_error)) = match band {
            Ok(band) => {
                let ts = band.t_times_s(0.95);
                let threads = opts.thread_count().clamp(1, used.len() / 16_384 + 1);
                let per = used.len().div_ceil(threads).max(1);
                // the half-widths of every row in one vector, each thread filling its part
                let mut hw = vec![0.0; used.len()];
                let refitted = std::thread::scope(|s| {
                    let refits = s.spawn(held_out);
                    let handles: Vec<_> = used
                        .chunks(per)
                        .zip(hw.chunks_mut(per))
                        .map(|(rows, out)| {
                            s.spawn(|| {
                                band.leverages_into(&refs, rows, out)?;
                                for h in out.iter_mut() {
                                    *h = ts * (1.0 + *h).sqrt();
                                }
                                anyhow::Ok(())
                            })
                        })
                        .collect();
                    for h in handles {
                        h.join().expect("leverage worker panicked")?;
                    }
                    anyhow::Ok(refits.join().expect("held-out worker panicked"))
                })?;
                ((crate::cli::trust::spread(hw), None), refitted)
            }
            Err(e) => (
                ((f64::NAN, f64::NAN, f64::NAN), Some(e.to_string())),
                held_out(),
            ),
        };
        let sel_names: Vec<String> = sel.iter().map(|&j| names[j].clone()).collect();
        let vif = variance_inflation_compressed(&sel_names, &full.r, full.rows, &rcols, &constant);
        Ok(Trust {
            pi95,
            pi_error,
            vif,
            held_out,
            held_out_error,
        })
    }

    /// The printed section.
    pub fn text(&self, response: &str) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        match &self.pi_error {
            None => {
                let _ = writeln!(
                    s,
                    "95 % prediction interval of {response} at the data's rows: ± {:.6} … {:.6} (median {:.6})",
                    self.pi95.0, self.pi95.2, self.pi95.1
                );
            }
            Some(e) => {
                let _ = writeln!(s, "no prediction interval: {e}");
            }
        }
        s += &crate::cli::trust::vif_text(&self.vif, "column");
        if let Some(e) = &self.held_out_error {
            let _ = writeln!(s, "held-out accuracy not computed: {e}");
        }
        if let Some(h) = &self.held_out {
            let _ = writeln!(
                s,
                "held-out accuracy ({} blocks of rows in file order, stepwise rerun without each): RMS {:.6}, max |error| {:.6} over {} rows",
                h.blocks, h.rms, h.max_abs, h.n
            );
        }
        s
    }

    /// As JSON.
    pub fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "prediction_interval_95_half_width": crate::cli::trust::spread_json(self.pi95),
            "prediction_interval_error": self.pi_error,
            "vif": crate::cli::trust::vif_json(&self.vif, "column"),
            "held_out": self.held_out.as_ref().map(crate::cli::trust::held_out_json),
            "held_out_error": self.held_out_error,
        })
    }
}

/// Held-out blocks as ranges of the used rows, or why there are none; `None`: none asked for.
pub type BlockRanges = Option<Result<Vec<(usize, usize)>, String>>;

/// The data `[x… y]` compressed once per block of rows for held-out accuracy: the full fit
/// merges every block's triangle, the fit without block `b` all but that one — one pass over
/// the data for the fit and all its held-out refits.
pub struct Blocks {
    /// The rows without NaN in `y` or any candidate, ascending.
    pub used: Vec<usize>,
    /// The held-out blocks as ranges of `used` (time order), or why there are none; `None`
    /// when none were asked for.
    pub ranges: BlockRanges,
    parts: Vec<CompressedPart>,
    n: usize,
}

impl Blocks {
    /// Compresses `[x… y]` in `blocks` contiguous blocks of the rows the fit uses (0: one).
    pub fn compress(
        x: &[&[f64]],
        y: &[f64],
        blocks: usize,
        threads: usize,
    ) -> anyhow::Result<Self> {
        let n = y.len();
        let mut cols: Vec<&[f64]> = x.to_vec();
        cols.push(y);
        // Optimistic: the common file has no NaN, and the compression finds any NaN in its
        // blocks while they are in cache anyway. A separate test first read all 41 columns on
        // one thread while the other core waited (≈ 5 % of the command's wall time); now only a
        // file with NaN pays for a second pass (the rows it uses, then the compression again).
        let all: Vec<usize> = (0..n).collect();
        let (used, ranges, parts) = Self::compress_rows(&cols, all, blocks, threads)?;
        let (used, ranges, parts) = if parts.iter().all(|p| p.left_out().is_empty()) {
            (used, ranges, parts)
        } else {
            let used: Vec<usize> = (0..n)
                .filter(|&i| !y[i].is_nan() && x.iter().all(|c| !c[i].is_nan()))
                .collect();
            Self::compress_rows(&cols, used, blocks, threads)?
        };
        Ok(Blocks {
            used,
            ranges,
            parts,
            n,
        })
    }

    /// Compresses `cols` in `blocks` blocks of the rows `used` (ascending; the rows without NaN).
    fn compress_rows(
        cols: &[&[f64]],
        used: Vec<usize>,
        blocks: usize,
        threads: usize,
    ) -> anyhow::Result<(Vec<usize>, BlockRanges, Vec<CompressedPart>)> {
        let n = cols.first().map_or(0, |c| c.len());
        let ranges = match blocks {
            0 => None,
            k => Some(
                crate::numerics::uncertainty::time_blocks(used.len(), k).map_err(|e| e.to_string()),
            ),
        };
        // block b starts at the input row of its first used row; NaN rows go with either
        // neighbour and are left out there as in the full fit
        let mut bounds = vec![0];
        if let Some(Ok(r)) = &ranges {
            bounds.extend(r.iter().skip(1).map(|&(start, _)| used[start]));
        }
        bounds.push(n);
        let parts = compress_parts(cols, true, threads, &bounds)?;
        Ok((used, ranges, parts))
    }

    /// The compression of every block but `leave_out`.
    pub fn merged(&self, leave_out: Option<usize>) -> Compressed {
        let keep: Vec<&CompressedPart> = self
            .parts
            .iter()
            .enumerate()
            .filter(|(b, _)| Some(*b) != leave_out)
            .map(|(_, p)| p)
            .collect();
        merge_parts(&keep, self.n)
    }
}
