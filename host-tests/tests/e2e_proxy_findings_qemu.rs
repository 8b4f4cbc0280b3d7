//! Issue 21's findings about the GCS proxy, each as the issue gives it, through the QEMU
//! firmware: the host's bytes go in on the board's host port (serial0, its line state wired),
//! the simulated PI controller (`nanocal::virtual_bench`) answers on the stage port, and the
//! test checks what the controller received and what the host got back. Every target the
//! controller accepts is compared with the model evaluated in f64 (`Model::eval_f64`) at the
//! target the host meant — from a base the controller itself reported, mapped back by an f64
//! bisection of the same model (independent of the model's own inverse) — within the f32
//! tolerance the other e2e tests use (0.1 nm; mapped replies 0.2 nm).
//!
//! The set-up is the issue's: a 1-axis E-727 whose travel (`TMN?`/`TMX?`) is 0…500 µm, and the
//! published 1-DoF model with the training envelope −24…504 µm (its correction at 0 µm is
//! −0.023 µm at the sensors' temperatures: just outside the controller's travel).
//!
//! | finding | test |
//! |---|---|
//! | 1 a relative move after a stop used a stale base (`4d5652203120310a18`) | `finding_1_a_relative_move_after_a_stop_starts_where_the_controller_stopped` |
//! | 2 `MVR` after a move the controller refused (`MOV 1 100 2 0.6`, `GOH 1 2`) | `finding_2_a_relative_move_after_a_refused_move_starts_where_the_controller_is` |
//! | 3 home and the travel limits (`MOV 1 0`, `GOH`, the ends of 0…500) | `finding_3_home_and_the_ends_of_the_controllers_travel` |
//! | 4 control characters hide a command (`0d4d4f562031203230300a`, …) | `finding_4_a_line_with_a_control_character_is_refused_not_forwarded` |
//! | 5 one unanswered query misaligned later replies (`POS? 5`, `RBT`) | `finding_5_an_unanswered_query_leaves_later_replies_paired` |
//! | 6 `PUN? 2` blocked every move on a 3-axis controller | `finding_6_the_hosts_pun_of_one_axis_does_not_block_moves` |
//! | 9 a new connection inherited the old one's bytes | `finding_9_a_new_connection_starts_clean` |
//!
//! Findings 7 and 8 (management port) are in `e2e_mgmt_qemu.rs`. Each test boots its own board
//! (independent; about a second each, the warm-up in lockstep). Nothing here waits on the wall
//! clock for something *not* to happen: "nothing was forwarded" is read from the controller's
//! record once the reply to a later query of the host's (a sentinel, `SVO? 1`) has come back;
//! the two places where the controller must answer *late* hold it (its lock) and the board's
//! clock (lockstep) until the board's own count of bytes written to the stage port says the
//! proxy has sent what comes first; other bounds are in the board's time. Without
//! qemu-system-arm the tests are skipped with a loud message, except in CI.

mod fw_sim;

use fw_sim::{
    in_service, next_host_line, own_query, stage_value, Config, Event, GcsHost, Qemu, SensorSim,
    StageSim, HANG,
};
use nanocal::papers::published::one_dof;
use nanocal_compensator::proxy::travel::CLAMP_UM;
use nanocal_interface::bench_link as bl;
use nanocal_model::{blob, Factor, Input, Model, ModelBuilder, SlowInputs, MAX_AXES};
use std::time::{Duration, Instant};

/// Temperatures the simulated sensors report (exact in MAX31856 LSBs), inside 21–23 °C.
const TEMPS_C: [f32; 4] = [22.0, 22.125, 21.875, 22.25];
/// The controller's travel of axis 1 (`TMN?`, `TMX?`), µm: the issue's.
const TMN_UM: f64 = 0.0;
const TMX_UM: f64 = 500.0;
/// The model's training envelope of axis 1, µm: the issue's.
const ENVELOPE_UM: (f64, f64) = (-24.0, 504.0);
/// Board time after the upload by which the model is in service (its sensors read, folded
/// twice, warmed up), s.
const WARM_UP_S: f64 = 6.0;
/// A forwarded command against the f64 reference, µm (e2e_qemu's).
const CMD_TOL_UM: f64 = 1e-4;
/// A mapped position against the f64 reference, µm (e2e_qemu's).
const MAP_TOL_UM: f64 = 2e-4;

/// The published 1-DoF model (its coefficients, travel −20…520 µm) with the issue's envelope
/// −24…504 µm (the scaling stays the training range's 0…480: the same polynomial).
fn issue_model() -> Model {
    use one_dof::*;
    let mut b = ModelBuilder::new(1, 4, 0)
        .unwrap()
        .id(0x0021_0001)
        .trained_range(Input::Axis(0), X_RANGE_UM.0, X_RANGE_UM.1)
        .envelope(Input::Axis(0), ENVELOPE_UM.0, ENVELOPE_UM.1)
        .travel_um(0, TRAVEL_UM.0, TRAVEL_UM.1);
    for t in 0..4 {
        b = b.trained_range(Input::Temp(t), T_RANGE_C.0, T_RANGE_C.1);
    }
    for (k, a) in A.iter().enumerate() {
        b.add_raw_term(0, [3 - k as u8, 0, 0], Factor::None, 0, *a)
            .unwrap();
    }
    for (t, coeff) in B_UM_PER_C.iter().enumerate() {
        b.add_raw_term(0, [0; MAX_AXES], Factor::Temp(t as u8), 0, *coeff)
            .unwrap();
    }
    b.offset_um(0, LAMBDA_UM).build().unwrap()
}

fn slow() -> SlowInputs {
    let mut s = SlowInputs::default();
    for (i, t) in TEMPS_C.iter().enumerate() {
        s.temps_c[i] = f64::from(*t);
    }
    s
}

/// The bytes of a hex string (the issue's inputs as it gives them).
fn hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// The value of a one-axis position reply `1=<value>`.
fn position(reply: &str) -> Option<f64> {
    reply.trim().strip_prefix("1=")?.parse().ok()
}

/// One board with the issue's controller and model, the model in service, a host connected.
struct Rig {
    /// Which finding the rig checks (every failure message names it).
    finding: u8,
    q: Qemu,
    stage: StageSim,
    _sensors: SensorSim,
    host: Option<GcsHost>,
    model: Model,
}

impl Rig {
    /// The board with an E-727 of `axes` axes (axis 1's travel 0…500 µm; stages that arrive at
    /// once), the issue's model uploaded and in service, and the host's port open (DTR).
    fn start(finding: u8, test: &str, axes: usize) -> Option<Rig> {
        let mut q = Qemu::start_or_skip(test)?;
        let mut cfg = Config::e727(axes).ready();
        for a in &mut cfg.axes {
            a.velocity = 1e12;
        }
        cfg.axes[0].min = TMN_UM;
        cfg.axes[0].max = TMX_UM;
        let stage = StageSim::serve(q.connect(1), cfg);
        let sensors = SensorSim::start(q.link(), &TEMPS_C);
        let model = issue_model();
        let mut b = vec![0u8; blob::MAX_BLOB_LEN];
        let n = blob::encode(&model, &mut b).unwrap();
        q.client().upload(&b[..n]).expect("upload the model");
        // the sensors' first fold periods pass in lockstep, as fast as the board runs (5.5 s
        // of its time at 1× were most of a test's wall time). Bytes announced to the board
        // that never reach it (a first request lost while it was still starting: the
        // client's retry) hold its clock until the free-running bench gives up on them
        // (`MAX_HOLD`); in lockstep nothing would: wait for that first.
        let link = q.link();
        let hang = Instant::now() + HANG;
        while (0..bl::SERIALS).any(|p| link.announced_unread(p) > 0) {
            assert!(Instant::now() < hang, "announced bytes never read");
            std::thread::sleep(Duration::from_millis(5));
        }
        let clk = q.clock();
        clk.lockstep();
        let now_s = clk.now_s();
        if let Err(e) = clk.advance_to(now_s + WARM_UP_S, Duration::from_secs(20)) {
            // (seen once in some 40 boots, cause not found: the board's clock stayed at 0;
            // the warm-up then runs at 1×, bounded in board time by `in_service`)
            eprintln!("\n*** {test}: the warm-up in lockstep stalled ({e:?}); at 1× instead\n");
        }
        clk.free_run(1.0);
        in_service(&mut q, model.id());
        let host = Some(q.gcs_host());
        Some(Rig {
            finding,
            q,
            stage,
            _sensors: sensors,
            host,
            model,
        })
    }

    fn host(&mut self) -> &mut GcsHost {
        self.host.as_mut().expect("a host connected")
    }

    /// The model's correction of target `x_um`, in f64.
    fn command(&self, x_um: f64) -> f64 {
        self.model
            .eval_f64(&[x_um, 0.0, 0.0], &[0; MAX_AXES], &slow())[0]
    }

    /// The calibrated position of command `q_um`: the f64 model inverted by bisection.
    fn calibrated(&self, q_um: f64) -> f64 {
        let (mut lo, mut hi) = (-100.0, 600.0);
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if self.command(mid) < q_um {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    /// The controller's target of axis 1.
    fn target(&self) -> f64 {
        self.stage.with(|c| c.target(0))
    }

    /// Targets axis 1 accepted since the last call.
    fn moves(&self) -> Vec<f64> {
        self.stage
            .events()
            .into_iter()
            .filter_map(|e| match e {
                Event::Target { axis: 0, value, .. } => Some(value),
                _ => None,
            })
            .collect()
    }

    /// Run `f` with the controller held (its lock: what the board sends it meanwhile is
    /// answered only afterwards, late) and the board's clock held (lockstep: no reply timeout
    /// runs out meanwhile, however loaded the machine); then the clock runs free again.
    fn held<R>(&mut self, f: impl FnOnce(&mut Qemu, &mut Option<GcsHost>) -> R) -> R {
        let clk = self.q.clock();
        clk.lockstep();
        let (stage, q, host) = (&self.stage, &mut self.q, &mut self.host);
        let r = stage.with(|_| f(q, host));
        clk.free_run(1.0);
        r
    }

    /// Ask the sentinel `SVO? 1` and return every line the controller received before it
    /// since the last call (the compensator's own queries included, its markers left out). Its reply coming back
    /// means everything the host sent before it was dealt with.
    fn sentinel(&mut self) -> Vec<String> {
        let f = self.finding;
        let reply = self.host().ask("SVO? 1");
        assert_eq!(
            reply, "1=1",
            "finding {f}: the sentinel SVO? 1 got another query's reply"
        );
        let mut lines = self.stage.drain_until(|l| l == "SVO? 1", HANG);
        lines.pop();
        // the proxy's markers (its `*IDN?` after a query the controller may leave unanswered,
        // the sentinel's among them): the host sends no `*IDN?` here
        lines.retain(|l| l != "*IDN?");
        lines
    }

    /// Send `bytes`; what the controller received for them.
    fn exchange(&mut self, bytes: &[u8]) -> Vec<String> {
        self.host().send_raw(bytes);
        self.sentinel()
    }

    /// The single corrected `MOV` among `lines`: its value against the f64 correction of
    /// `x_um`; the controller accepted it (its target, its only new target). Returns it.
    fn corrected(&self, lines: &[String], x_um: f64, what: &str) -> f64 {
        let f = self.finding;
        let movs: Vec<&String> = lines.iter().filter(|l| l.starts_with("MOV ")).collect();
        assert_eq!(
            movs.len(),
            1,
            "finding {f}: {what}: one corrected MOV expected, the controller received {lines:?}"
        );
        let got = stage_value(movs[0], "1");
        let want = self.command(x_um);
        assert!(
            (got - want).abs() <= CMD_TOL_UM,
            "finding {f}: {what}: sent {got}, the correction of {x_um:.4} is {want:.6} \
             (Δ = {:.1} nm; the correction of {:.4}): {lines:?}",
            (got - want) * 1e3,
            self.calibrated(got)
        );
        assert_eq!(self.moves(), [got], "finding {f}: {what}: accepted");
        assert_eq!(self.target(), got, "finding {f}: {what}");
        got
    }

    /// `MOV 1 x`, corrected and accepted.
    fn mov(&mut self, x_um: f64) -> f64 {
        let line = format!("MOV 1 {x_um}");
        let lines = self.exchange(format!("{line}\n").as_bytes());
        self.corrected(&lines, x_um, &line)
    }

    /// `MVR 1 d`: the base asked from the controller (`MOV? 1` before the move) and the move
    /// corrected from its calibrated position.
    fn mvr(&mut self, d_um: f64) -> f64 {
        let f = self.finding;
        let base = self.calibrated(self.target());
        let line = format!("MVR 1 {d_um}");
        let lines = self.exchange(format!("{line}\n").as_bytes());
        let sent = self.corrected(
            &lines,
            base + d_um,
            &format!("{line} from the controller's target, calibrated {base:.4}"),
        );
        let asked = lines.iter().position(|l| l == "MOV? 1");
        let moved = lines.iter().position(|l| l.starts_with("MOV "));
        assert!(
            asked.is_some() && asked < moved,
            "finding {f}: {line}: the base was not asked of the controller: {lines:?}"
        );
        sent
    }

    /// `bytes` are refused with GCS error `code` (the host's next `ERR?`, the first thing it
    /// reads), nothing of them reaches the controller and nothing moves.
    fn refused(&mut self, bytes: &[u8], code: &str, what: &str) {
        let f = self.finding;
        // (what the controller received before: not this line's)
        self.sentinel();
        let held = self.target();
        self.moves();
        self.host().send_raw(bytes);
        let err = self.host().ask("ERR?");
        let lines: Vec<String> = self
            .sentinel()
            .into_iter()
            .filter(|l| !own_query(l))
            .collect();
        // what moved first: the most telling failure
        assert_eq!(
            self.moves(),
            [] as [f64; 0],
            "finding {f}: {what}: moved (the controller received {lines:?})"
        );
        assert_eq!(self.target(), held, "finding {f}: {what}");
        assert!(
            lines.is_empty(),
            "finding {f}: {what}: forwarded {lines:?} (ERR? answered {err:?})"
        );
        assert_eq!(
            err, code,
            "finding {f}: {what}: the host's first line after it"
        );
    }
}

/// Wait until the board has written `n` bytes to the stage port since its count was `tx0`
/// (with its clock held: no board time passes; up to [`HANG`] of wall time, ringing the board
/// in case QEMU's loop sleeps on the host's socket).
fn stage_written(q: &Qemu, tx0: u32, n: u32, what: &str) {
    let link = q.link();
    fw_sim::wait_for(q, what, || link.tx_bytes(1).wrapping_sub(tx0) >= n);
}

/// Finding 1: `MOV 1 100`, `HLT 1`, then `MVR 1 1\n\x18` in one write. The proxy holds the
/// `MVR` for its base (`MOV? 1`); the stop goes out at once and drops it; the controller's
/// answer to that `MOV? 1` comes after the stop (the controller is held until the board has
/// written both) and must never become a base. Then `MOV 1 300`, `HLT 1`, `MVR 1 5` (the issue
/// saw ≈ 105 instead of ≈ 305) and `STP` at 401, `MVR 1 2` (≈ 102 instead of ≈ 403): each base
/// asked of the controller.
#[test]
fn finding_1_a_relative_move_after_a_stop_starts_where_the_controller_stopped() {
    let Some(mut r) = Rig::start(
        1,
        "finding_1_a_relative_move_after_a_stop_starts_where_the_controller_stopped",
        1,
    ) else {
        return;
    };
    r.mov(100.0);
    assert_eq!(r.exchange(b"HLT 1\n"), ["HLT 1"]);
    r.moves();
    let held = r.target();

    let bytes = hex("4d5652203120310a18");
    assert_eq!(bytes, b"MVR 1 1\n\x18");
    r.held(|q, host| {
        let tx0 = q.link().tx_bytes(1);
        host.as_mut().unwrap().send_raw(&bytes);
        // `MOV? 1\n` and the stop: on the stage link before the controller answers
        stage_written(q, tx0, 8, "finding 1: the proxy's MOV? 1 and the stop");
    });
    let lines = r.sentinel();
    assert_eq!(
        lines,
        ["MOV? 1", "#24"],
        "finding 1: the held MVR 1 1 went out"
    );
    assert_eq!(
        r.moves(),
        [] as [f64; 0],
        "finding 1: the held MVR 1 1 moved"
    );
    assert_eq!(r.target(), held);

    // no ERR? in between: a raw user's session
    r.mov(300.0);
    assert_eq!(r.exchange(b"HLT 1\n"), ["HLT 1"]);
    r.moves();
    let sent = r.mvr(5.0);
    assert!((r.calibrated(sent) - 305.0).abs() < 1e-3, "{sent}");
    r.mov(401.0);
    assert_eq!(r.exchange(b"STP\n"), ["STP"]);
    r.moves();
    let sent = r.mvr(2.0);
    assert!((r.calibrated(sent) - 403.0).abs() < 1e-3, "{sent}");
    assert_eq!(r.host().ask("ERR?"), "10", "finding 1: the stop's error");
}

/// Finding 2: the controller refuses `MOV 1 100 2 0.6` as a whole (a 1-axis controller: axis
/// 2 unknown, error 15) and stays where it was; the host does not ask `ERR?`; `MVR 1 -19.29`
/// must start from where the controller is (the issue saw a 150 µm jump: the base was the
/// refused 100). The same after a refused `GOH 1 2`. A relative move of the model's axis and
/// another (`MVR 1 5 2 1`) is refused (9016), not split: nothing moves.
#[test]
fn finding_2_a_relative_move_after_a_refused_move_starts_where_the_controller_is() {
    let Some(mut r) = Rig::start(
        2,
        "finding_2_a_relative_move_after_a_refused_move_starts_where_the_controller_is",
        1,
    ) else {
        return;
    };
    r.mov(250.0);
    for (refused, d) in [("MOV 1 100 2 0.6", -19.29), ("GOH 1 2", 3.0)] {
        let held = r.target();
        r.exchange(format!("{refused}\n").as_bytes());
        assert_eq!(
            r.moves(),
            [] as [f64; 0],
            "finding 2: {refused}: the controller refuses it as a whole"
        );
        assert_eq!(r.target(), held, "finding 2: {refused}");
        let sent = r.mvr(d);
        let at = r.calibrated(held) + d;
        assert!((r.calibrated(sent) - at).abs() < 1e-3, "{sent} {at}");
        assert_eq!(
            r.host().ask("ERR?"),
            "15",
            "finding 2: {refused}: the controller's error reaches the host"
        );
    }
    // a relative move of the model's axis and another is never split into a corrected `MOV`
    // the controller takes and an `MVR` it refuses
    r.refused(b"MVR 1 5 2 1\n", "9016", "MVR 1 5 2 1");
}

/// Finding 3: the model's envelope is −24…504 µm, the controller's travel 0…500 µm. `MOV 1 0`
/// and `GOH` (whose correction is 0.023 µm below the travel) are clamped to 0 (within
/// `CLAMP_UM`), and `MOV? 1` reports the calibrated position of what was sent; at 499.9 µm the
/// correction clamps to 500; further out (500 µm, −10 µm: inside the envelope) the move is
/// refused with 9012 and nothing moves; outside the envelope, 9001.
#[test]
fn finding_3_home_and_the_ends_of_the_controllers_travel() {
    let Some(mut r) = Rig::start(
        3,
        "finding_3_home_and_the_ends_of_the_controllers_travel",
        1,
    ) else {
        return;
    };
    // the set-up is the issue's: each case where it should be
    let (q0, q_top, q_out) = (r.command(0.0), r.command(499.9), r.command(500.0));
    assert!(TMN_UM - CLAMP_UM < q0 && q0 < TMN_UM, "{q0}");
    assert!(TMX_UM < q_top && q_top < TMX_UM + CLAMP_UM, "{q_top}");
    assert!(
        q_out > TMX_UM + CLAMP_UM && 500.0 <= ENVELOPE_UM.1,
        "{q_out}"
    );
    assert!(r.command(-10.0) < TMN_UM - CLAMP_UM && -10.0 >= ENVELOPE_UM.0);

    for home in ["MOV 1 0", "GOH"] {
        r.mov(200.0);
        let lines = r.exchange(format!("{home}\n").as_bytes());
        let movs: Vec<&String> = lines.iter().filter(|l| l.starts_with("MOV ")).collect();
        assert!(
            movs.len() == 1 && stage_value(movs[0], "1") == TMN_UM,
            "finding 3: {home}: clamped to the controller's travel, sent {lines:?}"
        );
        assert_eq!(
            r.moves(),
            [TMN_UM],
            "finding 3: {home}: the controller went home"
        );
        assert_eq!(
            r.host().ask("ERR?"),
            "0",
            "finding 3: {home}: the controller refused it"
        );
        let x = position(&r.host().ask("MOV? 1")).unwrap();
        let want = r.calibrated(TMN_UM);
        assert!(
            (x - want).abs() <= MAP_TOL_UM,
            "finding 3: {home}: MOV? 1 says {x}, the calibrated position of 0 is {want}"
        );
    }
    let lines = r.exchange(b"MOV 1 499.9\n");
    assert!(
        lines
            .iter()
            .any(|l| l.starts_with("MOV ") && stage_value(l, "1") == TMX_UM),
        "finding 3: MOV 1 499.9: clamped to {TMX_UM}, sent {lines:?}"
    );
    assert_eq!(r.moves(), [TMX_UM], "finding 3: MOV 1 499.9");
    r.mov(250.0);
    r.refused(b"MOV 1 500\n", "9012", "MOV 1 500 (0.127 µm beyond TMX)");
    r.refused(b"MOV 1 -10\n", "9012", "MOV 1 -10 (below TMN)");
    r.refused(b"MOV 1 -30\n", "9001", "MOV 1 -30 (outside the envelope)");
}

/// Finding 4: a line with a byte outside GCS's printable set (other than its LF and a CR
/// before it) is refused with 9011 and never forwarded: the issue's `\rMOV 1 200` (hex
/// `0d4d4f562031203230300a`, which moved a controller that takes CR for white space to exactly
/// 200, uncorrected), `MOV\r1 300`, `\rMVR 1 5` and `\rPOS?` (whose reply went to the host
/// unmapped).
#[test]
fn finding_4_a_line_with_a_control_character_is_refused_not_forwarded() {
    let Some(mut r) = Rig::start(
        4,
        "finding_4_a_line_with_a_control_character_is_refused_not_forwarded",
        1,
    ) else {
        return;
    };
    r.mov(100.0);
    let cr_mov = hex("0d4d4f562031203230300a");
    assert_eq!(cr_mov, b"\rMOV 1 200\n");
    for (bytes, what) in [
        (&cr_mov[..], "\\rMOV 1 200"),
        (b"MOV\r1 300\n", "MOV\\r1 300"),
        (b"\rMVR 1 5\n", "\\rMVR 1 5"),
        (b"\rPOS?\n", "\\rPOS?"),
    ] {
        r.refused(bytes, "9011", what);
    }
    // the check itself: the line without the control byte is corrected; a CR before the LF
    // is part of a line's end
    r.mov(200.0);
    let lines = r.exchange(b"MOV 1 150\r\n");
    r.corrected(&lines, 150.0, "MOV 1 150\\r\\n");
}

/// Finding 5: a controller leaves a query it rejects unanswered (`POS? 5` on a 1-axis
/// controller: error 15, no reply). Later replies stay paired with their queries: `ERR?` gets
/// 15, `POS? 1` its mapped position (the issue saw the raw position); also with both queries in
/// one write. After `RBT` the proxy reads the controller's facts again (its own `CSV?` among
/// them, whose reply the issue saw delivered to the host) while the host's `POS? 5` goes
/// unanswered: every reply the host gets is still its own query's.
#[test]
fn finding_5_an_unanswered_query_leaves_later_replies_paired() {
    let Some(mut r) = Rig::start(
        5,
        "finding_5_an_unanswered_query_leaves_later_replies_paired",
        1,
    ) else {
        return;
    };
    let mapped = |r: &mut Rig, what: &str, want: f64| {
        let line = r.host().read_line(HANG);
        let x = position(&line);
        assert!(
            x.is_some_and(|x| (x - want).abs() <= MAP_TOL_UM),
            "finding 5: {what}: the host got {line:?}, the mapped position is {want}"
        );
    };
    r.mov(100.0);
    r.host().send("POS? 5");
    assert_eq!(r.host().ask("ERR?"), "15", "finding 5: ERR? after POS? 5");
    r.host().send("POS? 1");
    mapped(&mut r, "POS? 1 after POS? 5", 100.0);
    r.host().send_raw(b"POS? 5\nPOS? 1\nERR?\n");
    mapped(&mut r, "POS? 5, POS? 1 in one write", 100.0);
    assert_eq!(
        r.host().read_line(HANG),
        "15",
        "finding 5: ERR? after POS? 5, POS? 1"
    );

    r.host().send("RBT");
    r.host().send("POS? 1");
    mapped(&mut r, "POS? 1 after RBT", 100.0);
    // the issue's case: a query the controller leaves unanswered while the proxy reads the
    // controller again (after RBT it knows no axes: the query goes out, with a marker), and
    // the first move
    r.host().send_raw(b"POS? 5\nMOV 1 150\nPOS? 1\n");
    mapped(&mut r, "POS? 1 after RBT, POS? 5 and MOV 1 150", 150.0);
    assert_eq!(
        r.host().ask("ERR?"),
        "15",
        "finding 5: ERR? after RBT, POS? 5, MOV 1 150, POS? 1"
    );
    let lines = r.sentinel();
    assert!(
        lines.iter().any(|l| l == "CSV?"),
        "finding 5: after RBT the proxy reads the controller again: {lines:?}"
    );
    r.corrected(&lines, 150.0, "MOV 1 150 after RBT");
}

/// Finding 6: on a 3-axis controller the host asks `PUN? 2` (before the first move, and
/// again after one); moves of the model's axis 1 are still corrected — the proxy's unit check
/// is its own `PUN? 1`, not what the host happened to ask (the issue saw 9007 on every move).
#[test]
fn finding_6_the_hosts_pun_of_one_axis_does_not_block_moves() {
    let Some(mut r) = Rig::start(
        6,
        "finding_6_the_hosts_pun_of_one_axis_does_not_block_moves",
        3,
    ) else {
        return;
    };
    for x in [100.0, 200.0] {
        let unit = r.host().ask("PUN? 2");
        assert!(
            unit.starts_with("2="),
            "finding 6: PUN? 2 answered {unit:?}"
        );
        let line = format!("MOV 1 {x}");
        r.host().send(&line);
        let err = r.host().ask("ERR?");
        assert_eq!(err, "0", "finding 6: {line} after PUN? 2 refused");
        let lines = r.sentinel();
        if x == 100.0 {
            assert!(
                lines.iter().any(|l| l == "PUN? 1"),
                "finding 6: the proxy's own unit query: {lines:?}"
            );
        }
        r.corrected(&lines, x, &format!("{line} after PUN? 2"));
    }
}

/// Finding 9: a new connection starts clean. A `POS? 1` sent just before the port closes is
/// forwarded, and the controller answers it only once the next connection's `ERR?` has been
/// forwarded too (held until then): that reply is not the new host's — its first line is the
/// answer to its own `ERR?`.
/// A line cut mid-way (`MOV 1 1`, no LF) does not join the next connection's first line (the
/// issue saw error 1 there).
#[test]
fn finding_9_a_new_connection_starts_clean() {
    let Some(mut r) = Rig::start(9, "finding_9_a_new_connection_starts_clean", 1) else {
        return;
    };
    r.mov(100.0);
    let next = r.held(|q, host| {
        let tx0 = q.link().tx_bytes(1);
        let mut old = host.take().unwrap();
        old.send("POS? 1");
        stage_written(
            q,
            tx0,
            7,
            "finding 9: POS? 1 forwarded before the port closes",
        );
        drop(old);
        // the board has read every byte sent; DTR falls, a new connection, DTR rises
        let mut next = q.reconnect_gcs();
        // the new host's first query reaches the controller before the controller answers
        // the old one (and QEMU has taken the new connection: its loop is rung meanwhile)
        next.send("ERR?");
        stage_written(q, tx0, 12, "finding 9: the new connection's ERR? forwarded");
        next
    });
    r.host = Some(next);
    for line in ["POS? 1", "ERR?"] {
        assert_eq!(next_host_line(&r.stage), line, "finding 9");
    }
    assert_eq!(
        r.host().read_line(HANG),
        "0",
        "finding 9: the new connection's first line (its ERR?'s answer)"
    );
    r.sentinel();

    r.host().send_raw(b"MOV 1 1");
    drop(r.host.take());
    r.host = Some(r.q.reconnect_gcs());
    let lines = r.exchange(b"MOV 1 200\n");
    r.corrected(&lines, 200.0, "MOV 1 200 after a line cut mid-way");
    assert_eq!(
        r.host().ask("ERR?"),
        "0",
        "finding 9: the new connection's ERR?"
    );
}
