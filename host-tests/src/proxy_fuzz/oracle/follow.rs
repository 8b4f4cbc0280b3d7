//! The oracle's side of following (issue 19, `compensator/src/proxy/follow.rs`): when the
//! setup follows the fold, a `MOV` of the proxy's own may reach the controller with no host
//! move behind it. It is legitimate only as a re-issue of the held host target:
//!
//! - following is armed: the last corrected host move reached the controller without an
//!   address prefix, and nothing since cancelled it — a stop, a reference move, a servo change
//!   (`HLT`, `STP`, `#24`, `#27`, `SVO`, `FRF`, …, `RBT`) of an axis the proxy maps, a non-zero
//!   `ERR?` answer (the host's or the proxy's own), a new host session, a sensor fault, a new
//!   model, following switched off;
//! - the controller holds exactly the command last sent for that target (a host move's, or the
//!   last re-issue's), on every model axis;
//! - its commands are the model's correction of the held target at the current fold, or, with
//!   a step limit, the held command moved towards it by at most the step; at least one axis
//!   moved by more than the threshold; the correction lies inside the travel;
//! - at least the interval after the host's move or the previous re-issue.
//!
//! A re-issue is the only command the proxy sends on its own besides its queries, so the
//! promise "every move the controller receives is the model's correction of a target the host
//! asked for" keeps its strength: the target is the host's, the fold one the device had (the
//! rig's current one), and the step what the settings allow.
//!
//! The proxy's own `ERR?` (its check before a re-issue, and the one after it) reads the
//! controller's error register: a host `ERR?` that arrives while the check is in flight is
//! answered by the proxy with the code the check read. A `0` answered that way is right only
//! when no host command before that `ERR?` failed after the check read the register.

use super::{Oracle, TOL_UM};
use crate::virtual_bench::Processed;
use nanocal_compensator::proxy::FollowConfig;
use nanocal_model::MAX_AXES;

/// Commands after which the proxy forgets the targets of the axes they name (all axes when
/// they name none): following stops. `true`: `{axis value}` pairs (axes at even positions).
const CANCELS: &[(&str, bool)] = &[
    ("HLT", false),
    ("STP", false),
    ("STF", false),
    ("FRF", false),
    ("FNL", false),
    ("FPL", false),
    ("REF", false),
    ("MNL", false),
    ("MPL", false),
    ("FED", false),
    ("INI", false),
    ("CLR", false),
    ("RNP", false),
    ("SVO", true),
    ("EAX", true),
];

/// The axis identifiers the proxy maps (its default axis names).
const MAPPED: [&str; 3] = ["1", "2", "3"];

/// The held target following may re-issue.
#[derive(Debug, Clone)]
struct Armed {
    /// The calibrated targets the commands may stand for (several when a relative move's base
    /// was ambiguous; narrowed by the first re-issue).
    cands: Vec<[f64; MAX_AXES]>,
    /// The commands the controller was sent for them, per model axis.
    q: Vec<f64>,
    /// No re-issue before this plus the interval, ms: the host move's step began here, or the
    /// last re-issue went.
    since_ms: u32,
}

/// Following as the oracle sees it.
#[derive(Debug, Default)]
pub(in crate::proxy_fuzz) struct FollowOracle {
    /// The setup follows.
    pub on: bool,
    /// The proxy's setting.
    pub cfg: FollowConfig,
    armed: Option<Armed>,
    /// The rig's time when the current step began, and now (ms).
    pub step_start_ms: u32,
    pub now_ms: u32,
    /// The next `ERR?` of the proxy's own is the one after a re-issue.
    expect_done: bool,
    /// Commands the controller processed, counted (an order for the two lists below).
    seq: u64,
    /// The proxy's checks that read 0: when (`seq`).
    zero_checks: Vec<u64>,
    /// Host commands that failed: when (`seq`), and the host line's id.
    failures: Vec<(u64, u64)>,
    /// Why the last `MOV` was not a re-issue (for the report when no host move explains it).
    pub why_not: Option<String>,
    /// Re-issues checked.
    pub reissues: u64,
}

impl FollowOracle {
    /// Following as a setup has it (`on`), not armed.
    pub fn new(on: bool) -> Self {
        Self {
            on,
            ..Default::default()
        }
    }

    /// Following stops until the next host move (the proxy cancelled it).
    pub fn cancel(&mut self) {
        self.armed = None;
    }

    /// Nothing is in flight anywhere: no host `ERR?` waits for an answer.
    pub fn quiet(&mut self) {
        self.zero_checks.clear();
        self.failures.clear();
    }

    /// A `0` the proxy answered to the host's `ERR?` `id`, which never reached the controller:
    /// right when a check of the proxy's read 0 and no host command before `id` failed after
    /// it.
    pub fn zero_answer_ok(&self, id: u64, reply: &[u8]) -> bool {
        let s = String::from_utf8_lossy(reply);
        let zero = s.lines().count() == 1 && s.trim().split(' ').next_back() == Some("0");
        self.on
            && zero
            && self.zero_checks.iter().any(|&at| {
                !self
                    .failures
                    .iter()
                    .any(|&(when, line)| when > at && line < id)
            })
    }
}

impl Oracle {
    /// Count one processed command; `host_id`: the host line it was, when it failed.
    pub(super) fn follow_seen(&mut self, p: &Processed, host_id: Option<u64>) {
        let f = &mut self.follow;
        if let (Some(id), Some(_)) = (host_id, p.failed) {
            f.failures.push((f.seq, id));
        }
    }

    /// The proxy's own `ERR?` reached the controller: a non-zero code stops following (a
    /// check read an error the host has not read, or the controller refused the re-issue).
    pub(super) fn follow_own_error(&mut self, p: &Processed) {
        let f = &mut self.follow;
        f.seq += 1;
        let code = error_code(&p.reply);
        let check = !std::mem::replace(&mut f.expect_done, false);
        if code != Some(0) {
            f.armed = None;
        } else if check {
            f.zero_checks.push(f.seq);
        }
    }

    /// A host line reached the controller (`word` upper case, `args` after it): the cancels.
    pub(super) fn follow_host_line(&mut self, p: &Processed, word: &str, args: &str, id: u64) {
        self.follow.seq += 1;
        self.follow_seen(p, Some(id));
        let toks: Vec<&str> = args.split(' ').filter(|t| !t.is_empty()).collect();
        let cancels = match CANCELS.iter().find(|(w, _)| *w == word) {
            Some(&(_, paired)) => {
                let axes: Vec<&str> = toks
                    .iter()
                    .copied()
                    .step_by(1 + usize::from(paired))
                    .collect();
                axes.is_empty() || axes.iter().any(|t| MAPPED.contains(t))
            }
            None => matches!(word, "RBT" | "#24" | "#27"),
        };
        let error_read = word == "ERR?" && error_code(&p.reply).is_some_and(|c| c != 0);
        if cancels || error_read {
            self.follow.armed = None;
        }
    }

    /// A corrected host move reached the controller (`got`: its model-axis commands, `before`:
    /// the controller's targets before it, `matched`: the targets it may stand for): it holds
    /// from now on, followed unless it had an address prefix.
    pub(super) fn follow_arm(
        &mut self,
        p: &Processed,
        got: &[(usize, f64)],
        before: &[f64],
        matched: &[[f64; MAX_AXES]],
        id: u64,
    ) {
        self.follow.seq += 1;
        self.follow_seen(p, Some(id));
        let mut q = before[..self.n].to_vec();
        for &(a, v) in got {
            q[a] = v;
        }
        // the targets the commands are the corrections of, or (a clamped command) the
        // calibrated position of what the controller holds
        let mut cands: Vec<[f64; MAX_AXES]> = matched
            .iter()
            .filter(|x| {
                let c = self.command(x);
                (0..self.n).all(|a| (c[a] - q[a]).abs() <= TOL_UM)
            })
            .copied()
            .collect();
        let at = self.inverse(&q);
        // the record the proxy keeps — the commands with the targets they stand for, or (a
        // clamped command) the calibrated position of what it sent, at this fold: the
        // controller holding them is there for bases and `MOV?` (the host's frame) until it
        // is sent something else, whatever the fold does since
        let records: Vec<[f64; MAX_AXES]> = if cands.is_empty() {
            vec![at]
        } else {
            cands.clone()
        };
        for x in records {
            if !self.sent.iter().any(|(sq, sx)| *sq == q && *sx == x) {
                if self.sent.len() == 16 {
                    self.sent.pop_front();
                }
                self.sent.push_back((q.clone(), x));
            }
        }
        cands.push(at);
        // (a move with an address prefix is recorded, not followed)
        let (prefix, _, _) = super::split(p.line.trim_end_matches('\r'));
        if !prefix.is_empty() {
            self.follow.armed = None;
            return;
        }
        self.follow.armed = Some(Armed {
            cands,
            q,
            since_ms: self.follow.step_start_ms,
        });
    }

    /// Is the `MOV` (`toks`: its arguments, `got`: its model-axis values, `before`: the
    /// controller's targets before it) a legitimate re-issue? On `Ok(true)` it is recorded.
    pub(super) fn follow_reissue(
        &mut self,
        p: &Processed,
        toks: &[&str],
        got: &[(usize, f64)],
        before: &[f64],
    ) -> bool {
        match self.reissue_check(p, toks, got, before) {
            Ok(x) => {
                let q: Vec<f64> = (0..self.n).map(|a| got[a].1).collect();
                let f = &mut self.follow;
                f.seq += 1;
                f.armed = Some(Armed {
                    cands: vec![x],
                    q: q.clone(),
                    since_ms: f.now_ms,
                });
                f.expect_done = true;
                f.reissues += 1;
                f.why_not = None;
                // the controller holding these commands holds the host's target (the proxy
                // records them as the ones sent for it: bases and `MOV?` map back to it)
                if self.sent.len() == 16 {
                    self.sent.pop_front();
                }
                self.sent.push_back((q, x));
                true
            }
            Err(why) => {
                self.follow.why_not = Some(why);
                false
            }
        }
    }

    fn reissue_check(
        &self,
        p: &Processed,
        toks: &[&str],
        got: &[(usize, f64)],
        before: &[f64],
    ) -> Result<[f64; MAX_AXES], String> {
        let f = &self.follow;
        let n = self.n;
        let Some(armed) = &f.armed else {
            return Err("not a re-issue: following is not armed (or was cancelled)".into());
        };
        let (prefix, _, _) = super::split(p.line.trim_end_matches('\r'));
        let in_order = got.iter().enumerate().all(|(i, &(a, _))| a == i);
        if !prefix.is_empty() || got.len() != n || toks.len() != 2 * n || !in_order {
            return Err("not a re-issue: not every model axis, in order, without prefix".into());
        }
        // (the controller's own arithmetic may leave a target a few ulps off the printed one)
        if (0..n).any(|a| (before[a] - armed.q[a]).abs() > 1e-9) {
            return Err(format!(
                "not a re-issue: the controller holds {:?}, not the commands sent for the held \
                 target {:?}",
                &before[..n],
                armed.q
            ));
        }
        let waited = f.now_ms.wrapping_sub(armed.since_ms);
        if waited < f.cfg.interval_ms {
            return Err(format!(
                "a re-issue {waited} ms after the host's move or the last re-issue (interval {} ms)",
                f.cfg.interval_ms
            ));
        }
        let thr_um = f64::from(f.cfg.threshold_nm) * 1e-3;
        let step_um = f64::from(f.cfg.max_step_nm) * 1e-3;
        let mut why = String::from("no held target");
        for x in &armed.cands {
            let want = self.command(x);
            let inside = (0..n).all(|a| {
                let (lo, hi) = self.travel[a];
                want[a] >= lo - TOL_UM && want[a] <= hi + TOL_UM
            });
            let beyond = (0..n).any(|a| (want[a] - armed.q[a]).abs() > thr_um - TOL_UM);
            let fits = (0..n).all(|a| {
                let d = want[a] - armed.q[a];
                let expect = if step_um > 0.0 {
                    armed.q[a] + d.clamp(-step_um, step_um)
                } else {
                    want[a]
                };
                (got[a].1 - expect).abs() <= TOL_UM
            });
            if inside && beyond && fits {
                return Ok(*x);
            }
            why = format!(
                "held target {:?}: the fold's command {:?} (inside the travel: {inside}, beyond \
                 the {} nm threshold: {beyond}), step limit {} nm",
                &x[..n],
                &want[..n],
                f.cfg.threshold_nm,
                f.cfg.max_step_nm
            );
        }
        let gq: Vec<f64> = got.iter().map(|&(_, v)| v).collect();
        let stands = self.inverse(&gq);
        Err(format!(
            "not the re-issue of the held target: {why}; its commands stand for {:?} at this \
             fold",
            &stands[..n]
        ))
    }
}

/// The code of an `ERR?` reply (after an address prefix, if any).
fn error_code(reply: &[u8]) -> Option<i32> {
    let s = String::from_utf8_lossy(reply);
    if s.lines().count() != 1 {
        return None;
    }
    s.trim().split(' ').next_back()?.parse().ok()
}
