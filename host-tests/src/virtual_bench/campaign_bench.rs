//! The QEMU board as a campaign's bench: `nanocal campaign --virtual` (and the campaign's tests)
//! open it here and hand it to [`crate::campaign::run_on`]. The campaign itself opens only real
//! benches, so it depends on no simulator: this is the one place that joins the two.

use super::bench::{Faults, VirtualBench};
use crate::campaign::bench::{BenchDriver, ReferenceReader};
use crate::campaign::gcs::GcsLink;
use crate::campaign::reference::{self, ClockMap, ClockMode};
use crate::campaign::run::{CampaignError, Links, Reopen};
use crate::campaign::state::{BenchSpec, VirtualBoard};
use crate::data::plan::{Plan, Step};
use crate::device::Client;
use std::time::Duration;

/// Opens the QEMU bench for `spec` (a [`BenchSpec::Virtual`] on the QEMU board), staging
/// `faults`: the opener [`crate::campaign::run_on`] takes.
pub fn opener(
    faults: Faults,
) -> impl FnMut(&BenchSpec, &Plan, &[Step], usize) -> Result<Links, CampaignError> {
    move |spec, plan, steps, resume_at| open(spec, plan, steps, resume_at, &faults)
}

/// Starts QEMU with the digital twin of `plan` in lockstep for the campaign's `steps` (from step
/// `resume_at` on), and returns the campaign's links to it.
pub fn open(
    spec: &BenchSpec,
    plan: &Plan,
    steps: &[Step],
    resume_at: usize,
    faults: &Faults,
) -> Result<Links, CampaignError> {
    let seed = match spec {
        BenchSpec::Virtual {
            seed,
            board: VirtualBoard::Qemu,
        } => *seed,
        other => {
            return Err(CampaignError::NotReady {
                step: resume_at,
                what: format!("the QEMU bench cannot run a campaign for {other:?}"),
            })
        }
    };
    if !super::have_qemu() {
        return Err(CampaignError::NotReady {
            step: resume_at,
            what: "the virtual bench needs qemu-system-arm ≥ 10 and the thumbv7em-none-eabihf target (`bash .ci/firmware.sh` installs both)".into(),
        });
    }
    let plan_start = steps.get(resume_at).map_or(0.0, |s| s.t_start_s);
    let twin = crate::campaign::virtual_twin(plan, seed)?;
    let traj = crate::twin::execute::trajectory(steps);
    let mut vb = VirtualBench::start(
        &twin,
        &traj,
        crate::twin::examples::TRAINING_START_S,
        seed,
        plan_start - VirtualBench::SETUP_S,
        faults,
    );
    let device = Client::new(
        vb.management(),
        "virtual:management",
        Duration::from_secs(10),
    );
    let gcs = GcsLink::new(vb.gcs(), "virtual:gcs");
    let mut ports = vb.port_opener();
    let reopen: Reopen = Box::new(move || {
        let (m, g) = ports().map_err(|e| CampaignError::NotReady {
            step: 0,
            what: format!("reopening the virtual compensator's ports: {e}"),
        })?;
        Ok((
            Client::new(m, "virtual:management", Duration::from_secs(10)),
            GcsLink::new(g, "virtual:gcs"),
        ))
    });
    let src = reference::open(&vb.reference_spec(), plan.training.axes(), 1.0)?;
    let reference = ReferenceReader::new(src, ClockMap::new(ClockMode::Synchronized));
    let driver: Box<dyn BenchDriver> = Box::new(vb);
    Ok(Links {
        driver,
        device,
        gcs,
        reference,
        reopen: Some(reopen),
    })
}
