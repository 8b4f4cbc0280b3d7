//! Benchmark image for the QEMU board: runs the fast path and the proxy's MOV line path in
//! regions delimited by calls to `nanocal_bench_start`/`nanocal_bench_stop`, which the
//! instruction-counting TCG plugin (tools/qemu-plugin/insn_count.c) watches. Exits through
//! semihosting. Regions (each `N` iterations, `N/10` for the folds) are listed in `REGIONS`
//! of host-tests/tests/fw_bench.rs, in this order:
//! 0 empty loop (overhead), 1 `Fold::correct` 1-DoF/8 terms, 2 `Fold::correct` 2-DoF/40 terms,
//! 3 a `MOV` line through the proxy (the host's bytes with LF in, the corrected line out: line
//! assembly, parse, correct, format; 1-DoF), 4 `Model::eval_f64` 1-DoF (the slow path's
//! soft-float f64 for comparison), 5 `Fold::inverse` 1-DoF, 6 `Model::fold` 2-DoF (the slow
//! path), 7 `Fold::correct` 1-DoF + 16 play operators along a walk with reversals, 8
//! `Fold::correct` 3-DoF/78 terms (paper 001's robot size), 9 `Fold::correct` 1-DoF + a fast
//! force input, 10 region 7's walk, each command followed by `Fold::inverse_from` of its reply
//! started at the target (1-DoF + 16 play operators, state frozen), 11 `Fold::inverse` 3-DoF/78
//! terms, 12 `Fold::inverse_from` 1-DoF started at the last target, 13 `Model::fold` 3-DoF/78
//! terms. Position replies through the published 1-DoF model: 14 a `MOV` line, then the host's
//! `POS? 1` and the controller's reply 3 nm off the command, mapped back, 15 the same `MOV` lines
//! alone (subtracted from 14 and 16), 16 a `MOV` line, then `MOV? 1` answered with the command
//! sent, 17 `HLT 1`, then `POS? 1` mapped with no target known, 18 `HLT 1` alone (subtracted
//! from 17), 19 the round of 14 through the 8-term model (region 3's `MOV` lines subtracted),
//! 20 `Fold::inverse` of the published model, 21 the CRC-32 of the largest management frame
//! (kind, seq, length and a 320-byte payload: what the device computes per frame it receives
//! and per reply it seals).
#![no_std]
#![no_main]

use core::hint::black_box;
use core::ptr::addr_of_mut;
use core::sync::atomic::{compiler_fence, Ordering};
use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use nanocal_compensator::gcs::LineBuf;
use nanocal_compensator::proxy::{FoldCorrector, Output, Proxy};
use nanocal_model::reference::delta_robot_78;
use nanocal_model::{
    AuxKind, AuxSpec, Factor, FastInputs, HysteresisState, Input, Model, ModelBuilder, SlowInputs,
    Term, MAX_AXES,
};

/// Iterations per region.
const N: u32 = 1000;

static mut MARK: u32 = 0;

/// Start of a measured region (the plugin starts counting at its first instruction).
#[no_mangle]
#[inline(never)]
pub extern "C" fn nanocal_bench_start(region: u32) {
    // SAFETY: a volatile store to a private static (keeps the two markers distinct functions).
    unsafe { core::ptr::write_volatile(addr_of_mut!(MARK), region | 0x1000) };
    compiler_fence(Ordering::SeqCst);
}

/// End of a measured region.
#[no_mangle]
#[inline(never)]
pub extern "C" fn nanocal_bench_stop(region: u32) {
    compiler_fence(Ordering::SeqCst);
    // SAFETY: as above.
    unsafe { core::ptr::write_volatile(addr_of_mut!(MARK), region | 0x2000) };
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("bench panic: {}", info);
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

fn term(output: u8, powers: [u8; MAX_AXES], factor: Factor, coeff: f64) -> Term {
    Term {
        output,
        powers,
        factor,
        direction: 0,
        coeff,
    }
}

/// What the 1-DoF model carries besides its 8 terms.
#[derive(Clone, Copy, PartialEq)]
enum Extra {
    None,
    /// A bank of 16 play operators (thresholds 0–225 µm over the 480 µm stroke).
    Hysteresis,
    /// A fast force input (aux 0, N) in two terms: F and x·F.
    Force,
}

/// 1-DoF, 8 terms: x (the identity plus a scale error), x²…x⁵, two temperatures, x·T₀; plus
/// `extra`. Near the identity like every stage model, so the inverse sees a realistic map.
fn model_1dof(extra: Extra) -> Option<Model> {
    let aux = usize::from(extra == Extra::Force);
    let mut b = ModelBuilder::new(1, 2, aux)
        .ok()?
        .id(0xB1)
        .trained_range(Input::Axis(0), 0.0, 480.0)
        .trained_range(Input::Temp(0), 21.0, 23.0)
        .trained_range(Input::Temp(1), 21.0, 23.0)
        .travel_um(0, -20.0, 520.0);
    b.add_raw_term(0, [1, 0, 0], Factor::None, 0, 1.0).ok()?;
    for (k, c) in [1.2, -0.3, 0.05, -0.01, 0.002].iter().enumerate() {
        b.add_term(term(0, [k as u8 + 1, 0, 0], Factor::None, *c))
            .ok()?;
    }
    b.add_term(term(0, [0; 3], Factor::Temp(0), 2.9)).ok()?;
    b.add_term(term(0, [0; 3], Factor::Temp(1), -3.1)).ok()?;
    b.add_term(term(0, [1, 0, 0], Factor::Temp(0), 0.4)).ok()?;
    match extra {
        Extra::None => {}
        Extra::Hysteresis => {
            let bank: [(f64, f64); 16] =
                core::array::from_fn(|k| (15.0 * k as f64, -0.01 - 0.001 * k as f64));
            b.play_bank(0, &bank).ok()?;
        }
        Extra::Force => {
            b = b
                .trained_range(Input::Aux(0), -2.0, 2.0)
                .aux_spec(0, AuxSpec::fast(AuxKind::ForceN));
            b.add_term(term(0, [0; 3], Factor::Aux(0), 0.6)).ok()?;
            b.add_term(term(0, [1, 0, 0], Factor::Aux(0), 0.1)).ok()?;
        }
    }
    b.build().ok()
}

/// 2-DoF, 40 terms: per output own x…x⁵, cross y…y⁵, six mixed products, two temperatures,
/// x·T and y·T.
fn model_2dof() -> Option<Model> {
    let mut b = ModelBuilder::new(2, 2, 0).ok()?.id(0xB2);
    for a in 0..2u8 {
        b = b
            .trained_range(Input::Axis(a), 0.0, 80.0)
            .trained_range(Input::Temp(a), 20.0, 24.0)
            .travel_um(a as usize, -10.0, 100.0);
    }
    for out in 0..2u8 {
        let (own, other) = (out as usize, 1 - out as usize);
        for k in 1..=5u8 {
            let mut p = [0u8; 3];
            p[own] = k;
            b.add_term(term(out, p, Factor::None, 0.5 / f64::from(k)))
                .ok()?;
            let mut p = [0u8; 3];
            p[other] = k;
            b.add_term(term(out, p, Factor::None, 0.01 / f64::from(k)))
                .ok()?;
        }
        for (px, py) in [(1, 1), (2, 1), (1, 2), (2, 2), (3, 1), (1, 3)] {
            b.add_term(term(out, [px, py, 0], Factor::None, 1e-3))
                .ok()?;
        }
        b.add_term(term(out, [0; 3], Factor::Temp(0), 0.3)).ok()?;
        b.add_term(term(out, [0; 3], Factor::Temp(1), -0.2)).ok()?;
        b.add_term(term(out, [1, 0, 0], Factor::Temp(out), 0.01))
            .ok()?;
        b.add_term(term(out, [0, 1, 0], Factor::Temp(out), 0.02))
            .ok()?;
    }
    b.offset_um(0, 40.0).offset_um(1, 40.0).build().ok()
}

/// The published 1-DoF piezo-stage model (`host-tests/src/papers/published.rs`, paper 000): a cubic in
/// the position, four temperatures, an offset — a calibration map close to the identity, as
/// every physical one is. The position replies are mapped through it.
fn model_published() -> Option<Model> {
    let mut b = ModelBuilder::new(1, 4, 0)
        .ok()?
        .id(0x0001_0001)
        .trained_range(Input::Axis(0), 0.0, 480.0)
        .travel_um(0, -20.0, 520.0);
    for t in 0..4 {
        b = b.trained_range(Input::Temp(t), 21.0, 23.0);
    }
    for (k, a) in [2.454e-8, -2.167e-5, 1.005].iter().enumerate() {
        b.add_raw_term(0, [3 - k as u8, 0, 0], Factor::None, 0, *a)
            .ok()?;
    }
    #[allow(clippy::approx_constant)] // −3.142 µm/°C is a measured coefficient, not π
    let b_um_per_c = [2.978, -3.142, -0.996, 0.690];
    for (t, coeff) in b_um_per_c.iter().enumerate() {
        b.add_raw_term(0, [0; MAX_AXES], Factor::Temp(t as u8), 0, *coeff)
            .ok()?;
    }
    b.offset_um(0, 10.413).build().ok()
}

fn slow(t: f64) -> SlowInputs {
    let mut s = SlowInputs::default();
    for (k, v) in s.temps_c.iter_mut().enumerate() {
        *v = t + 0.1 * k as f64;
    }
    s
}

/// The `i`-th target of a walk over 0–480 µm with reversals and minor loops: a triangle of
/// period 200 with a smaller triangle of period 14 on top.
fn walk_um(i: u32) -> f32 {
    let tri = |i: u32, period: u32| {
        let p = (i % period) as f32 / period as f32;
        if p < 0.5 {
            2.0 * p
        } else {
            2.0 - 2.0 * p
        }
    };
    400.0 * tri(i, 200) + 80.0 * tri(i, 14)
}

/// Tell the proxy what a controller tells it before the first move: its identification, GCS
/// 2.0, axis 1, in µm, its travel (the same bytes a controller sends; the first MOV waits for
/// them).
fn prime(proxy: &mut Proxy, c: &FoldCorrector, out: &mut Output) {
    proxy.host_bytes(Some(c), b"MOV 1 1\n", 0, out);
    let asked = out.to_stage.clone();
    let mut replies = nanocal_compensator::gcs::LineBuf::<512>::new();
    for line in asked.as_bytes().split(|&b| b == b'\n') {
        let reply: &[u8] = match line {
            b"*IDN?" => b"(c)2026 Physik Instrumente (PI) GmbH & Co. KG, E-727, bench\n",
            b"CSV?" => b"2.0\n",
            b"SAI?" => b"1\n",
            b"PUN? 1" => b"1=\xB5m\n",
            b"TMN? 1" => b"1=-20\n",
            b"TMX? 1" => b"1=520\n",
            _ => b"",
        };
        let _ = replies.extend(reply);
    }
    let mut i = 0;
    while i < replies.len() {
        i += proxy.stage_bytes(Some(c), &replies.as_bytes()[i..], 0, out);
    }
    if proxy.holding() || proxy.unit_mismatch() || proxy.controller_identity().is_none() {
        panic!("the proxy did not take the controller's answers");
    }
}

#[entry]
fn main() -> ! {
    let (Some(m1), Some(m2), Some(mh), Some(mf), Ok(m3)) = (
        model_1dof(Extra::None),
        model_2dof(),
        model_1dof(Extra::Hysteresis),
        model_1dof(Extra::Force),
        delta_robot_78(),
    ) else {
        panic!("bench models rejected by the builder");
    };
    hprintln!(
        "terms: 1-DoF {}, 2-DoF {}, 1-DoF + bank {} ({} operators), 1-DoF + force {}, 3-DoF {}",
        m1.terms().len(),
        m2.terms().len(),
        mh.terms().len(),
        mh.play_operators().len(),
        mf.terms().len(),
        m3.terms().len()
    );
    let f1 = m1.fold(&slow(22.0));
    let f2 = m2.fold(&slow(22.0));
    let fh = mh.fold(&slow(22.0));
    let ff = mf.fold(&slow(22.0));
    let f3 = m3.fold(&slow(22.0));
    let dir = [0i8; MAX_AXES];
    let none = FastInputs::NONE;
    let mut state = HysteresisState::new();
    let mut acc = 0.0f32;

    nanocal_bench_start(0);
    for i in 0..N {
        acc += black_box(i as f32);
    }
    nanocal_bench_stop(0);

    nanocal_bench_start(1);
    for i in 0..N {
        let x = [black_box(i as f32 * 0.48), 0.0, 0.0];
        acc += f1.correct(&x, &dir, &none, &mut state).q_um[0];
    }
    nanocal_bench_stop(1);

    nanocal_bench_start(2);
    for i in 0..N {
        let x = [
            black_box(i as f32 * 0.08),
            black_box(80.0 - i as f32 * 0.08),
            0.0,
        ];
        acc += f2.correct(&x, &dir, &none, &mut state).q_um[1];
    }
    nanocal_bench_stop(2);

    let c1 = FoldCorrector::new(&m1, &slow(22.0));
    let mut proxy = Proxy::default();
    let mut out = Output::new();
    prime(&mut proxy, &c1, &mut out);
    let lines: [&[u8]; 4] = [
        b"MOV 1 123.456\n",
        b"MOV 1 7.25\n",
        b"MOV 1 300.0001\n",
        b"MOV 1 42\n",
    ];
    nanocal_bench_start(3);
    for i in 0..N {
        let used = proxy.host_bytes(Some(&c1), black_box(lines[(i % 4) as usize]), i, &mut out);
        acc += used as f32 + out.to_stage.len() as f32;
    }
    nanocal_bench_stop(3);

    let s = slow(22.0);
    nanocal_bench_start(4);
    for i in 0..N {
        let x = [black_box(f64::from(i) * 0.48), 0.0, 0.0];
        acc += m1.eval_f64(&x, &dir, &s)[0] as f32;
    }
    nanocal_bench_stop(4);

    nanocal_bench_start(5);
    for i in 0..N {
        let q = [black_box(i as f32 * 0.48), 0.0, 0.0];
        acc += f1
            .inverse(&q, &dir, &none, &state)
            .map(|x| x[0])
            .unwrap_or(0.0);
    }
    nanocal_bench_stop(5);

    nanocal_bench_start(6);
    for i in 0..N / 10 {
        let f = m2.fold(&slow(21.0 + f64::from(i) * 0.01));
        acc += f.correct(&[1.0, 1.0, 0.0], &dir, &none, &mut state).q_um[0];
    }
    nanocal_bench_stop(6);

    let mut hysteresis = HysteresisState::new();
    nanocal_bench_start(7);
    for i in 0..N {
        let x = [black_box(walk_um(i)), 0.0, 0.0];
        acc += fh.correct(&x, &dir, &none, &mut hysteresis).q_um[0];
    }
    nanocal_bench_stop(7);

    nanocal_bench_start(8);
    for i in 0..N {
        let v = black_box(i as f32 * 9.0 - 4500.0);
        let x = [v, -0.5 * v, 0.25 * v + 100.0];
        acc += f3.correct(&x, &dir, &none, &mut state).q_um[2];
    }
    nanocal_bench_stop(8);

    nanocal_bench_start(9);
    for i in 0..N {
        let x = [black_box(i as f32 * 0.48), 0.0, 0.0];
        let force = FastInputs::NONE.with_aux(0, black_box((i % 40) as f32 * 0.1 - 2.0));
        acc += ff.correct(&x, &dir, &force, &mut state).q_um[0];
    }
    nanocal_bench_stop(9);

    // The same walk, each command followed by a position query (the reply 3 nm off the
    // command, the operators frozen where the command left them), started at the command's
    // target as the proxy can: fw_bench subtracts region 7 to get the inverse's share.
    let mut hysteresis = HysteresisState::new();
    nanocal_bench_start(10);
    for i in 0..N {
        let x = [black_box(walk_um(i)), 0.0, 0.0];
        let q = fh.correct(&x, &dir, &none, &mut hysteresis).q_um;
        let reply = [black_box(q[0] + 0.003), 0.0, 0.0];
        acc += fh
            .inverse_from(&reply, &dir, &none, &hysteresis, &x)
            .map(|x| x[0])
            .unwrap_or(0.0);
    }
    nanocal_bench_stop(10);

    nanocal_bench_start(11);
    for i in 0..N {
        let v = black_box(i as f32 * 9.0 - 4500.0);
        let q = [v, -0.5 * v, 0.25 * v + 100.0];
        acc += f3
            .inverse(&q, &dir, &none, &state)
            .map(|x| x[2])
            .unwrap_or(0.0);
    }
    nanocal_bench_stop(11);

    // A reply to the last command, started at its target (the proxy knows it): the controller
    // reports the command back to within its servo error (here 3 nm).
    let mut replies = [[0.0f32; 2]; N as usize];
    for (i, r) in replies.iter_mut().enumerate() {
        let x = i as f32 * 0.48;
        let q = f1.correct(&[x, 0.0, 0.0], &dir, &none, &mut state).q_um;
        *r = [x, q[0] + 0.003];
    }
    nanocal_bench_start(12);
    for [x, q] in replies {
        let reply = [black_box(q), 0.0, 0.0];
        acc += f1
            .inverse_from(&reply, &dir, &none, &state, &[x, 0.0, 0.0])
            .map(|x| x[0])
            .unwrap_or(0.0);
    }
    nanocal_bench_stop(12);

    nanocal_bench_start(13);
    for i in 0..N / 10 {
        let f = m3.fold(&slow(21.0 + f64::from(i) * 0.01));
        acc += f.correct(&[1.0, 1.0, 1.0], &dir, &none, &mut state).q_um[0];
    }
    nanocal_bench_stop(13);

    // position replies, mapped through the published model
    let Some(mp) = model_published() else {
        panic!("published model rejected by the builder");
    };
    let mut sp = slow(22.0);
    sp.temps_c[2] = 21.9;
    sp.temps_c[3] = 22.2;
    let cp = FoldCorrector::new(&mp, &sp);
    let mut proxy = Proxy::default();
    prime(&mut proxy, &cp, &mut out);
    // POS? while the stage sits at the last target (sensor noise of a few nm)
    let targets: [&[u8]; 4] = [
        b"MOV 1 123.456\n",
        b"MOV 1 7.25\n",
        b"MOV 1 300.0001\n",
        b"MOV 1 42\n",
    ];
    let mut replies = [
        LineBuf::<32>::new(),
        LineBuf::new(),
        LineBuf::new(),
        LineBuf::new(),
    ];
    let mut sent = [
        LineBuf::<32>::new(),
        LineBuf::new(),
        LineBuf::new(),
        LineBuf::new(),
    ];
    for k in 0..4 {
        proxy.host_bytes(Some(&cp), targets[k], 0, &mut out);
        // "MOV 1 <q>\n" → the controller reports q − 3 nm, and exactly q for MOV?
        let q = &out.to_stage.as_bytes()[6..out.to_stage.len() - 1];
        let q = nanocal_compensator::gcs::parse_micros(q).unwrap_or(0);
        let _ = replies[k].extend(b"1=");
        let _ = replies[k].push_micros(q - 3_000);
        let _ = replies[k].push(b'\n');
        let _ = sent[k].extend(b"1=");
        let _ = sent[k].push_micros(q);
        let _ = sent[k].push(b'\n');
    }
    nanocal_bench_start(14);
    for i in 0..N {
        let k = (i % 4) as usize;
        proxy.host_bytes(Some(&cp), targets[k], i, &mut out);
        proxy.host_bytes(Some(&cp), black_box(b"POS? 1\n"), i, &mut out);
        proxy.stage_bytes(Some(&cp), black_box(replies[k].as_bytes()), i, &mut out);
        acc += out.to_host.len() as f32;
    }
    nanocal_bench_stop(14);
    // the MOV line alone, to subtract from regions 7 and 9
    nanocal_bench_start(15);
    for i in 0..N {
        let k = (i % 4) as usize;
        proxy.host_bytes(Some(&cp), targets[k], i, &mut out);
        acc += out.to_stage.len() as f32;
    }
    nanocal_bench_stop(15);

    nanocal_bench_start(16);
    for i in 0..N {
        let k = (i % 4) as usize;
        proxy.host_bytes(Some(&cp), targets[k], i, &mut out);
        proxy.host_bytes(Some(&cp), black_box(b"MOV? 1\n"), i, &mut out);
        proxy.stage_bytes(Some(&cp), black_box(sent[k].as_bytes()), i, &mut out);
        acc += out.to_host.len() as f32;
    }
    nanocal_bench_stop(16);

    nanocal_bench_start(17);
    for i in 0..N {
        let k = (i % 4) as usize;
        proxy.host_bytes(Some(&cp), black_box(b"HLT 1\n"), i, &mut out);
        proxy.host_bytes(Some(&cp), black_box(b"POS? 1\n"), i, &mut out);
        proxy.stage_bytes(Some(&cp), black_box(replies[k].as_bytes()), i, &mut out);
        acc += out.to_host.len() as f32;
    }
    nanocal_bench_stop(17);

    // the HLT line alone, to subtract from region 10
    nanocal_bench_start(18);
    for i in 0..N {
        proxy.host_bytes(Some(&cp), black_box(b"HLT 1\n"), i, &mut out);
        acc += out.to_stage.len() as f32;
    }
    nanocal_bench_stop(18);

    // the same round through the 8-term model (nearly flat: a poor case for any inverse)
    let mut proxy1 = Proxy::default();
    prime(&mut proxy1, &c1, &mut out);
    let mut replies1 = [
        LineBuf::<32>::new(),
        LineBuf::new(),
        LineBuf::new(),
        LineBuf::new(),
    ];
    for k in 0..4 {
        proxy1.host_bytes(Some(&c1), lines[k], 0, &mut out);
        let q = &out.to_stage.as_bytes()[6..out.to_stage.len() - 1];
        let q = nanocal_compensator::gcs::parse_micros(q).unwrap_or(0);
        let _ = replies1[k].extend(b"1=");
        let _ = replies1[k].push_micros(q - 3_000);
        let _ = replies1[k].push(b'\n');
    }
    nanocal_bench_start(19);
    for i in 0..N {
        let k = (i % 4) as usize;
        proxy1.host_bytes(Some(&c1), lines[k], i, &mut out);
        proxy1.host_bytes(Some(&c1), black_box(b"POS? 1\n"), i, &mut out);
        proxy1.stage_bytes(Some(&c1), black_box(replies1[k].as_bytes()), i, &mut out);
        acc += out.to_host.len() as f32;
    }
    nanocal_bench_stop(19);

    // the model's own inverse on the published model, for comparison
    let fp = mp.fold(&sp);
    nanocal_bench_start(20);
    for i in 0..N {
        let q = [black_box(10.0 + i as f32 * 0.47), 0.0, 0.0];
        acc += fp
            .inverse(&q, &dir, &none, &state)
            .map(|x| x[0])
            .unwrap_or(0.0);
    }
    nanocal_bench_stop(20);

    // the project's one CRC-32 (the model's, a nibble table) over the largest management frame
    let mut frame = [0u8; 4 + nanocal_interface::mgmt::MAX_PAYLOAD];
    nanocal_bench_start(21);
    for i in 0..N {
        frame[0] = i as u8;
        acc += nanocal_interface::crc32(black_box(&frame)) as f32;
    }
    nanocal_bench_stop(21);

    hprintln!("bench done (N = {}, checksum {})", N, acc);
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
