//! `nanocal campaign --virtual --board stm32` (issue 16 §2): a short campaign on the emulated
//! B-L475E-IOT01A running the shipped STM32 image, with the digital twin around it as on the
//! QEMU board (controller and stage on UART4, temperature chips on SPI1, the interferometer),
//! through the library's [`campaign::run_on`] with the `stm32-bench` crate's bench — what the
//! `stm32-bench` binary runs. Board time only: the result does not depend on the machine's load.

use nanocal::campaign::run::Quiet;
use nanocal::campaign::state::{BenchSpec, VirtualBoard};
use nanocal::campaign::{self, Config, Faults};
use nanocal::data::plan::{Plan, TestKind};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// Paper 000's 1-DoF procedure, cut short as `campaign_virtual.rs` cuts it: 4 training cycles
/// (47 min of plan time), one cycle per test, one round of no model / adaptive / static.
fn short_plan() -> Plan {
    Plan::paper000_1dof().shortened(4, 1, 1)
}

#[test]
fn stm32_campaign_corrects_the_stage_and_its_table_agrees_with_validate() {
    let out = std::env::temp_dir().join(format!("nanocal-campaign-stm32-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let cfg = Config {
        plan: Some(short_plan()),
        out: out.clone(),
        bench: Some(BenchSpec::Virtual {
            seed: 3,
            board: VirtualBoard::Stm32,
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
        faults: Faults::default(),
    };
    let o = campaign::run_on(
        &cfg,
        &mut nanocal_stm32_bench::bench::open,
        Arc::new(AtomicBool::new(false)),
        &mut Quiet,
    )
    .expect("the campaign runs on the emulated STM32 board");

    // the whole plan ran, on one boot of the board, with the models uploaded
    assert_eq!(o.state.next_step, short_plan().schedule().len());
    assert_eq!(o.state.device_resets, 0, "{:?}", o.state.interruptions);
    assert!(o.state.uploaded.is_some(), "a model was uploaded");
    assert!(o.state.kmz_updates > 0, "the KMZ was re-measured");

    // the table from what the firmware sent to the stage agrees with the file-based validate
    let a = &o.analysis;
    let names: Vec<&str> = a.campaign.iter().map(|r| r.compensation.name()).collect();
    assert_eq!(
        names,
        [
            TestKind::NoModel.name(),
            TestKind::Adaptive.name(),
            TestKind::Static.name()
        ]
    );
    assert!(
        a.max_difference_nm < 1.0,
        "table vs validate: {} nm",
        a.max_difference_nm
    );

    // the firmware corrected: with a model, the stage is far closer than without
    let acc_nm = |k: TestKind| {
        a.campaign
            .iter()
            .find(|r| r.compensation.name() == k.name())
            .map(|r| r.summary.max_acc_um * 1e3)
            .expect("the compensation's row")
    };
    let (none, adaptive, fixed) = (
        acc_nm(TestKind::NoModel),
        acc_nm(TestKind::Adaptive),
        acc_nm(TestKind::Static),
    );
    eprintln!("largest Acc, nm: no model {none:.1}, adaptive {adaptive:.1}, static {fixed:.1}");
    assert!(
        adaptive < none / 3.0 && fixed < none / 3.0,
        "no model {none:.1} nm, adaptive {adaptive:.1} nm, static {fixed:.1} nm"
    );
    let _ = std::fs::remove_dir_all(out);
}
