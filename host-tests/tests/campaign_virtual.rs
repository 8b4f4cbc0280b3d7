//! `nanocal campaign` on the virtual bench: the QEMU firmware between the campaign and the twin
//! (controller, interferometer, sensor chips), with short plans so that CI stays quick.
//!
//! - the table from what the firmware sent to the stage agrees with the file-based `validate`
//!   of the same recording within 1 nm, for every compensation (issue 12);
//! - a campaign stopped (Ctrl-C) and resumed gives the recording and the fit of one that ran
//!   through;
//! - an unreachable device, a pose outside the travel, an instrument that falls silent and a
//!   thermocouple that opens mid-campaign each stop it with a clear message and keep what was
//!   recorded; a compensator reset mid-campaign is noticed and the campaign goes on, also when
//!   the reset takes the compensator's ports away (USB) and they must be reopened.

use nanocal::campaign::run::{CampaignError, Progress, Quiet};
use nanocal::campaign::state::{BenchSpec, State, VirtualBoard};
use nanocal::campaign::{self, Config, Faults, Outcome, RECORDING};
use nanocal::data::plan::{Phase, Plan, TestKind};
use nanocal::virtual_bench::bench::Faults as BenchFaults;
use nanocal::virtual_bench::{campaign_bench, qemu_or_skip};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Paper 000's 1-DoF procedure, cut short: 4 training cycles (47 min of plan time), one cycle
/// per test, one round of no model / adaptive / static.
fn short_plan() -> Plan {
    Plan::paper000_1dof().shortened(4, 1, 1)
}

/// The steps of `plan`'s tests of `kind`, in order.
fn steps_of(plan: &Plan, kind: TestKind) -> Vec<usize> {
    plan.schedule()
        .iter()
        .enumerate()
        .filter(|(_, s)| matches!(s.phase, Phase::Test { kind: k, .. } if k == kind))
        .map(|(i, _)| i)
        .collect()
}

fn fresh_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("nanocal-campaign-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn config(out: &Path, plan: Option<Plan>, faults: Faults) -> Config {
    Config {
        plan,
        out: out.to_path_buf(),
        bench: Some(BenchSpec::Virtual {
            seed: 3,
            board: VirtualBoard::Qemu,
        }),
        sample_period_ms: None,
        fold_period_ms: None,
        safe_pose_um: None,
        sensor_names: None,
        design: None,
        explain: false,
        target_accuracy_nm: None,
        loop_tests: None,
        max_loops: 3,
        resume: false,
        faults,
    }
}

/// Runs `cfg` on the QEMU bench as `nanocal campaign --virtual` does: the caller opens the
/// bench, here staging the bench's own `faults`.
fn run_on_qemu(cfg: &Config, faults: BenchFaults) -> Result<Outcome, CampaignError> {
    campaign::run_on(
        cfg,
        &mut campaign_bench::opener(faults),
        Arc::new(AtomicBool::new(false)),
        &mut Quiet,
    )
}

fn run(cfg: &Config) -> Result<Outcome, CampaignError> {
    run_on_qemu(cfg, BenchFaults::default())
}

/// Rows of the recording (header excluded).
fn rows(dir: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(dir.join(RECORDING)).expect("the recording is there");
    text.lines().skip(1).map(str::to_string).collect()
}

fn row_t_s(row: &str) -> f64 {
    row.split(',')
        .next()
        .and_then(|t| t.parse().ok())
        .expect("a time")
}

/// Presses Ctrl-C when step `at` starts.
struct CtrlCAt {
    at: usize,
    stop: Arc<AtomicBool>,
}

impl Progress for CtrlCAt {
    fn step(&mut self, k: usize, _n: usize, _what: &str) {
        if k == self.at {
            self.stop.store(true, Ordering::Release);
        }
    }
    fn note(&mut self, _text: &str) {}
}

/// Per compensation: the largest difference between the table from what the stage received
/// and the file-based `validate` of the same recording, nm.
fn differences_nm(o: &Outcome) -> Vec<(String, f64)> {
    o.analysis
        .campaign
        .iter()
        .zip(&o.analysis.file)
        .map(|(c, f)| {
            (
                c.compensation.name().to_string(),
                nanocal::campaign::analysis::difference_nm(c, f),
            )
        })
        .collect()
}

/// The table agrees with `validate` within 1 nm for every compensation.
fn agrees_within_1_nm(o: &Outcome) {
    let d = differences_nm(o);
    assert_eq!(d.len(), 3, "no model, adaptive, static: {d:?}");
    for (_, nm) in &d {
        assert!(nm.is_finite() && *nm < 1.0, "{d:?}");
    }
}

/// Issue 12: the table computed from what the firmware sent agrees with the file-based
/// `validate` of the same recording within 1 nm — for every compensation.
#[test]
fn campaign_table_agrees_with_file_based_validate_within_1_nm() {
    if !qemu_or_skip("campaign_table_agrees_with_file_based_validate_within_1_nm") {
        return;
    }
    let out = fresh_dir("agree");
    let o = run(&config(&out, Some(short_plan()), Faults::default())).expect("campaign runs");
    let d = differences_nm(&o);
    eprintln!("|table − validate| per compensation, nm: {d:?}");
    assert!(
        o.analysis.max_difference_nm < 1.0 && d.iter().all(|(_, nm)| *nm < 1.0),
        "{d:?}"
    );
    let _ = std::fs::remove_dir_all(out);
}

#[test]
fn a_campaign_stopped_and_resumed_gives_the_rows_and_result_of_one_run_through() {
    if !qemu_or_skip("a_campaign_stopped_and_resumed") {
        return;
    }
    let plan = short_plan();
    let steps = plan.schedule();

    // straight through
    let whole = fresh_dir("whole");
    let o = run(&config(&whole, Some(plan.clone()), Faults::default())).expect("campaign runs");
    let a = &o.analysis;
    assert_eq!(a.campaign.len(), 3, "no model, adaptive, static");
    for (c, f) in a.campaign.iter().zip(&a.file) {
        assert_eq!(c.compensation.name(), f.compensation.name());
        assert!(!c.tests.is_empty(), "{} has tests", c.compensation.name());
        assert_eq!(c.tests.len(), f.tests.len());
    }
    agrees_within_1_nm(&o);
    assert_eq!(
        o.state.kmz_updates, 1,
        "the KMZ at the adaptive test's first visit"
    );
    assert!(whole.join("static.blob").exists() && whole.join("report").is_dir());

    // stopped in validation (after the fit), then resumed
    let first_test = steps
        .iter()
        .position(|s| matches!(s.phase, Phase::Test { .. }))
        .expect("validation steps");
    let cut = first_test + 5;
    let parted = fresh_dir("parted");
    let stop = Arc::new(AtomicBool::new(false));
    let err = campaign::run_on(
        &config(&parted, Some(plan.clone()), Faults::default()),
        &mut campaign_bench::opener(BenchFaults::default()),
        stop.clone(),
        &mut CtrlCAt {
            at: cut,
            stop: stop.clone(),
        },
    )
    .err()
    .expect("Ctrl-C stops it");
    assert!(
        matches!(err, CampaignError::Interrupted { step, .. } if step == cut),
        "{err}"
    );
    assert!(err.to_string().contains("--resume"), "{err}");
    let st = State::load(&parted).expect("state kept");
    // the steps whose rows are complete are committed: the one under way is done again
    assert_eq!(st.next_step, cut - 1);
    let kept = rows(&parted);
    assert!(!kept.is_empty());
    assert!(row_t_s(kept.last().expect("rows")) < steps[cut - 1].t_start_s);

    let mut again = config(&parted, None, Faults::default());
    again.bench = None;
    again.resume = true;
    let r = run(&again).expect("the resumed campaign finishes");

    // the same training poses at the same instants, recorded once each
    let (w, p) = (rows(&whole), rows(&parted));
    assert!(
        p.len() >= kept.len() && p[..kept.len()] == kept[..],
        "the rows before the stop are kept"
    );
    let times = |v: &[String]| v.iter().map(|r| row_t_s(r)).collect::<Vec<_>>();
    let (tw, tp) = (times(&w), times(&p));
    let first_difference = tw.iter().zip(&tp).position(|(a, b)| a != b);
    assert!(
        tw.len() == tp.len() && first_difference.is_none(),
        "no sample lost or doubled at the resume: {} vs {} rows, first difference at row {first_difference:?}",
        tw.len(),
        tp.len()
    );
    assert_eq!(r.state.interruptions.len(), 1);
    agrees_within_1_nm(&r);
    // the same result: the twin is the same at the same plan times; the two runs differ in the
    // instants the firmware read its sensors between exchanges (type K reading noise ≈ 16 mK
    // folded into the model: a few nm; a broken resume — a lost step, a refit on other data,
    // a model not uploaded again — moves an accuracy by tens to hundreds of nm)
    println!(
        "Acc through vs resumed, nm: {:?}",
        o.analysis
            .file
            .iter()
            .zip(&r.analysis.file)
            .map(|(x, y)| x
                .tests
                .iter()
                .zip(&y.tests)
                .map(|(a, b)| (a.accuracy_um * 1e3, b.accuracy_um * 1e3))
                .collect::<Vec<_>>())
            .collect::<Vec<_>>()
    );
    for (x, y) in o.analysis.file.iter().zip(&r.analysis.file) {
        assert_eq!(x.tests.len(), y.tests.len());
        for (tx, ty) in x.tests.iter().zip(&y.tests) {
            // the resumed board starts a new clock, so its folds fall at other instants and
            // read other sensor noise: the static tests have differed by up to 12 nm (41.1 vs
            // 29.1 nm) between a resumed and an uninterrupted run, the others by < 1 nm
            assert!(
                (tx.accuracy_um - ty.accuracy_um).abs() < 25e-3,
                "{}: Acc {} vs {} µm",
                x.compensation.name(),
                tx.accuracy_um,
                ty.accuracy_um
            );
        }
    }
    for d in [whole, parted] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn an_unreachable_device_is_named_and_nothing_is_recorded() {
    let out = fresh_dir("unreachable");
    let mut cfg = config(&out, Some(short_plan()), Faults::default());
    cfg.bench = Some(BenchSpec::Real {
        device: "tcp:127.0.0.1:1".into(),
        gcs: "tcp:127.0.0.1:1".into(),
        reference: "tcp:127.0.0.1:1".into(),
        reference_to_um: 1.0,
        reference_synchronized: true,
    });
    // a real bench: the campaign opens it itself
    let e = campaign::run(&cfg, Arc::new(AtomicBool::new(false)), &mut Quiet)
        .err()
        .expect("no device there");
    assert!(matches!(e, CampaignError::Device(_)), "{e:?}");
    assert!(e.to_string().contains("127.0.0.1:1"), "{e}");
    assert!(!out.join(RECORDING).exists());
    let _ = std::fs::remove_dir_all(out);
}

/// The campaign opens only real benches: a virtual one must come from its caller (the CLI),
/// and asking the campaign to open one is refused by name, with nothing recorded.
#[test]
fn the_campaign_does_not_open_a_virtual_bench_itself() {
    let out = fresh_dir("virtual-by-caller");
    let cfg = config(&out, Some(short_plan()), Faults::default());
    let e = campaign::run(&cfg, Arc::new(AtomicBool::new(false)), &mut Quiet)
        .err()
        .expect("refused");
    assert!(matches!(e, CampaignError::NotReady { .. }), "{e:?}");
    assert!(e.to_string().contains("opened by the caller"), "{e}");
    assert!(!out.join(RECORDING).exists());
    let _ = std::fs::remove_dir_all(out);
}

#[test]
fn a_pose_outside_the_travel_stops_the_campaign_before_the_first_move() {
    if !qemu_or_skip("a_pose_outside_the_travel") {
        return;
    }
    let out = fresh_dir("travel");
    let mut plan = short_plan();
    // the simulated E-727 travels −20…520 µm
    plan.training.cycle_um[3] = vec![600.0];
    let e = run(&config(&out, Some(plan), Faults::default()))
        .err()
        .expect("refused");
    match &e {
        CampaignError::OutsideTravel {
            step, pose_um, max, ..
        } => {
            assert_eq!(*step, 3);
            assert_eq!(*pose_um, 600.0);
            assert_eq!(*max, 520.0);
        }
        e => panic!("{e:?}"),
    }
    assert!(e.to_string().contains("outside the stage's travel"), "{e}");
    // no step ran: no campaign is left in the folder, the fixed plan can start there
    assert!(!out.join(RECORDING).exists() && State::load(&out).is_err());
    let _ = std::fs::remove_dir_all(out);
}

/// The campaign stopped at plan time around `t_s` with `e`; what was recorded up to it is there.
fn kept_up_to(out: &Path, t_s: f64, within_s: f64) {
    let r = rows(out);
    let last = row_t_s(r.last().expect("rows kept"));
    assert!(
        last < t_s + within_s && last > t_s - within_s,
        "last row at {last} s, fault at {t_s} s"
    );
    let st = State::load(out).expect("state kept");
    assert_eq!(st.interruptions.len(), 1);
    assert!(st.next_step > 0);
}

#[test]
fn an_instrument_that_falls_silent_stops_the_campaign_and_keeps_the_recording() {
    if !qemu_or_skip("an_instrument_that_falls_silent") {
        return;
    }
    let out = fresh_dir("silent");
    let t_s = 600.0;
    let faults = BenchFaults {
        reference_silent_from_s: Some(t_s),
        ..Default::default()
    };
    let e = run_on_qemu(&config(&out, Some(short_plan()), Faults::default()), faults)
        .err()
        .expect("stopped");
    let msg = e.to_string();
    assert!(
        matches!(e, CampaignError::Reference(_)) && msg.contains("sent no sample"),
        "{msg}"
    );
    kept_up_to(&out, t_s, 30.0);
    let _ = std::fs::remove_dir_all(out);
}

#[test]
fn a_thermocouple_that_opens_mid_campaign_is_named_and_the_recording_kept() {
    if !qemu_or_skip("a_thermocouple_that_opens") {
        return;
    }
    let out = fresh_dir("open-tc");
    let t_s = 900.0;
    let faults = BenchFaults {
        thermocouple_open: Some((1, t_s)),
        ..Default::default()
    };
    let e = run_on_qemu(&config(&out, Some(short_plan()), Faults::default()), faults)
        .err()
        .expect("stopped");
    let msg = e.to_string();
    assert!(matches!(e, CampaignError::SensorFault { .. }), "{e:?}");
    assert!(
        msg.contains("chip-select 1") && msg.contains("--resume"),
        "{msg}"
    );
    kept_up_to(&out, t_s, 30.0);
    let _ = std::fs::remove_dir_all(out);
}

#[test]
fn a_compensator_reset_mid_campaign_is_seen_and_the_campaign_goes_on() {
    if !qemu_or_skip("a_compensator_reset") {
        return;
    }
    let out = fresh_dir("reset");
    let plan = short_plan();
    // during the static test: the model is in service, the compensator must come back to it
    let at = steps_of(&plan, TestKind::Static)
        .last()
        .expect("a static test")
        - 3;
    let faults = Faults {
        reset_before_step: Some(at),
        ..Default::default()
    };
    let o = run(&config(&out, Some(plan), faults)).expect("the campaign goes on");
    assert_eq!(o.state.device_resets, 1);
    assert_eq!(o.state.interruptions.len(), 1);
    assert_eq!(o.state.interruptions[0].step, at);
    agrees_within_1_nm(&o);
    let _ = std::fs::remove_dir_all(out);
}

/// A reset on USB takes the compensator's ports away: the campaign's handles die (staged: they
/// fail as a vanished tty does), it opens both ports again, sees the reset in the status, sets
/// the device up again and goes on — with the table still the file-based `validate`'s.
#[test]
fn a_reset_that_takes_the_ports_away_is_reopened_and_the_campaign_goes_on() {
    if !qemu_or_skip("a_reset_that_takes_the_ports_away") {
        return;
    }
    let out = fresh_dir("ports");
    let plan = short_plan();
    let at = steps_of(&plan, TestKind::Adaptive)[0] + 2;
    let faults = Faults {
        ports_lost_before_step: Some(at),
        ..Default::default()
    };
    let o = run(&config(&out, Some(plan), faults)).expect("the campaign goes on");
    assert_eq!(o.state.device_resets, 1);
    let what: Vec<&str> = o
        .state
        .interruptions
        .iter()
        .map(|i| i.what.as_str())
        .collect();
    assert_eq!(what.len(), 2, "{what:?}");
    assert!(what[0].contains("ports went away"), "{what:?}");
    assert!(what[1].contains("compensator reset"), "{what:?}");
    assert!(o.state.interruptions.iter().all(|i| i.step == at));
    agrees_within_1_nm(&o);
    let _ = std::fs::remove_dir_all(out);
}

/// Periods other than the virtual bench's defaults (sample 1 s, fold 5 s): a 5 s sample period,
/// and a 10 s fold averaging ten readings — the table still agrees with the file-based
/// `validate` within 1 nm (it did not with 5 s before the replay read each row's recorded fold:
/// 9.5 nm on the published run).
#[test]
fn other_sample_and_fold_periods_agree_with_file_based_validate_within_1_nm() {
    if !qemu_or_skip("other_sample_and_fold_periods") {
        return;
    }
    for (sample, fold) in [(5000, 5000), (1000, 10_000)] {
        let out = fresh_dir(&format!("fold{fold}"));
        let mut cfg = config(&out, Some(short_plan()), Faults::default());
        cfg.sample_period_ms = Some(sample);
        cfg.fold_period_ms = Some(fold);
        let o = run(&cfg).expect("campaign");
        assert_eq!(
            (o.state.sample_period_ms, o.state.fold_period_ms),
            (sample, fold)
        );
        agrees_within_1_nm(&o);
        let _ = std::fs::remove_dir_all(out);
    }
}

/// Paper 001 §II, step 5: "Validation (evaluation of the robot absolute accuracy) and eventually
/// return to 1. (if the desired absolute accuracy has not yet been reached and consider other
/// sources of inaccuracy), or return to 0. (if all the possible sources of inaccuracy have
/// already been considered)."
///
/// The twin's stage hides a 20 min structural lag and ±5 nm of hysteresis. With a desired
/// accuracy below what the static model reaches, the loop runs explain on the validation,
/// finds both, adds them as the blob carries them (lag filters, a play-operator bank), fits the
/// static model again on the training data and validates it in a block of tests through the
/// firmware: the block's mean test accuracy improves on the model before it (evaluated on the
/// same block), and the firmware's table agrees with the file-based validation.
#[test]
fn the_validate_and_return_loop_finds_the_lag_and_the_hysteresis_and_improves() {
    if !qemu_or_skip("the_validate_and_return_loop") {
        return;
    }
    let out = fresh_dir("loop");
    let mut cfg = config(
        &out,
        Some(Plan::paper000_1dof().shortened(40, 5, 4)),
        Faults::default(),
    );
    // the README's run (`--shorten 40,5,4 --target-accuracy-nm 15 --loop-tests 4`, seed 1)
    cfg.bench = Some(BenchSpec::Virtual {
        seed: 1,
        board: VirtualBoard::Qemu,
    });
    cfg.target_accuracy_nm = Some(15.0);
    cfg.loop_tests = Some(4);
    cfg.max_loops = 1;
    let o = run(&cfg).expect("campaign with the loop");
    let lp = o.state.loops.as_ref().expect("loop state");
    eprintln!("{}", nanocal::cli::campaign::loops_table(lp));
    assert_eq!(lp.loops.len(), 1);
    let l = &lp.loops[0];
    let added: Vec<&str> = l.added.iter().map(|e| e.name.as_str()).collect();
    assert!(added.contains(&"thermal_lag on x"), "{added:?}");
    assert!(added.contains(&"hysteresis on x"), "{added:?}");
    assert!(l.acc_from_nm > 15.0, "the static model misses the target");
    let (before, after) = (l.before.expect("block ran"), l.after.expect("block ran"));
    assert!(
        after.mean_nm < 0.85 * before.mean_nm,
        "the refitted model improves the block: {before:?} → {after:?}"
    );
    // the recording carries one fold a step (the move's); the lag filters ran on every 5 s fold,
    // whose phase against the moves differs from run to run (when QEMU's UART hands the line
    // over): the file-based replay of a lag model agrees to a few nm, not 1 (3.2, 3.4, 6.2 nm
    // in three runs)
    assert!(l.agreement_nm.expect("compared") < 10.0);
    assert!(matches!(
        lp.stop,
        Some(campaign::LoopStop::MaxLoops | campaign::LoopStop::TargetMet { .. })
    ));
    // the block ran through the compensator with the refitted model
    let steps = Plan::paper000_1dof()
        .shortened(40, 5, 4)
        .schedule_with_blocks(1, 4);
    assert_eq!(o.state.next_step, steps.len());
    assert!(out.join("static-1.blob").exists() && out.join("static-0.blob").exists());
    agrees_within_1_nm(&o);
    let _ = std::fs::remove_dir_all(out);
}
