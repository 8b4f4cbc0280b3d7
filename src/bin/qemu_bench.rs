//! Benchmark image for the QEMU board: runs the fast path and the proxy's MOV line path in
//! regions delimited by calls to `nanocal_bench_start`/`nanocal_bench_stop`, which the
//! instruction-counting TCG plugin (tools/qemu-plugin/insn_count.c) watches. Exits through
//! semihosting. Regions (each `N` iterations):
//! 0 empty loop (overhead), 1 `Fold::correct` 1-DoF/8 terms, 2 `Fold::correct` 2-DoF/40 terms,
//! 3 a `MOV` line through the proxy (parse, correct, format; 1-DoF), 4 `Model::eval_f64` 1-DoF
//! (the slow path's soft-float f64 for comparison), 5 `Fold::inverse` 1-DoF, 6 `Model::fold`
//! 2-DoF (the slow path).
#![no_std]
#![no_main]

use core::hint::black_box;
use core::ptr::addr_of_mut;
use core::sync::atomic::{compiler_fence, Ordering};
use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln};
use nanocal_compensator::proxy::{FoldCorrector, Out, Proxy};
use nanocal_model::{Factor, Input, Model, ModelBuilder, SlowInputs, Term, MAX_AXES};

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

/// 1-DoF, 8 terms: x…x⁵, two temperatures, x·T₀.
fn model_1dof() -> Option<Model> {
    let mut b = ModelBuilder::new(1, 2, 0)
        .ok()?
        .id(0xB1)
        .trained_range(Input::Axis(0), 0.0, 480.0)
        .trained_range(Input::Temp(0), 21.0, 23.0)
        .trained_range(Input::Temp(1), 21.0, 23.0)
        .travel_um(0, -20.0, 520.0);
    for (k, c) in [1.2, -0.3, 0.05, -0.01, 0.002].iter().enumerate() {
        b.add_term(term(0, [k as u8 + 1, 0, 0], Factor::None, *c))
            .ok()?;
    }
    b.add_term(term(0, [0; 3], Factor::Temp(0), 2.9)).ok()?;
    b.add_term(term(0, [0; 3], Factor::Temp(1), -3.1)).ok()?;
    b.add_term(term(0, [1, 0, 0], Factor::Temp(0), 0.4)).ok()?;
    b.offset_um(0, 240.0).build().ok()
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

fn slow(t: f64) -> SlowInputs {
    let mut s = SlowInputs::default();
    s.temps_c[0] = t;
    s.temps_c[1] = t + 0.1;
    s
}

#[entry]
fn main() -> ! {
    let (Some(m1), Some(m2)) = (model_1dof(), model_2dof()) else {
        panic!("bench models rejected by the builder");
    };
    hprintln!(
        "terms: 1-DoF {}, 2-DoF {}",
        m1.terms().len(),
        m2.terms().len()
    );
    let f1 = m1.fold(&slow(22.0));
    let f2 = m2.fold(&slow(22.0));
    let dir = [0i8; MAX_AXES];
    let mut acc = 0.0f32;

    nanocal_bench_start(0);
    for i in 0..N {
        acc += black_box(i as f32);
    }
    nanocal_bench_stop(0);

    nanocal_bench_start(1);
    for i in 0..N {
        let x = [black_box(i as f32 * 0.48), 0.0, 0.0];
        acc += f1.correct(&x, &dir).q_um[0];
    }
    nanocal_bench_stop(1);

    nanocal_bench_start(2);
    for i in 0..N {
        let x = [
            black_box(i as f32 * 0.08),
            black_box(80.0 - i as f32 * 0.08),
            0.0,
        ];
        acc += f2.correct(&x, &dir).q_um[1];
    }
    nanocal_bench_stop(2);

    let c1 = FoldCorrector::new(&m1, &slow(22.0));
    let mut proxy = Proxy::default();
    let mut out = Out::new();
    let lines: [&[u8]; 4] = [
        b"MOV 1 123.456",
        b"MOV 1 7.25",
        b"MOV 1 300.0001",
        b"MOV 1 42",
    ];
    nanocal_bench_start(3);
    for i in 0..N {
        let r = proxy.host_line(Some(&c1), black_box(lines[(i % 4) as usize]), &mut out);
        acc += r as u32 as f32 + out.len() as f32;
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
        let q = [black_box(240.0 + i as f32 * 0.4), 0.0, 0.0];
        acc += f1.inverse(&q, &dir).map(|x| x[0]).unwrap_or(0.0);
    }
    nanocal_bench_stop(5);

    nanocal_bench_start(6);
    for i in 0..N / 10 {
        let f = m2.fold(&slow(21.0 + f64::from(i) * 0.01));
        acc += f.correct(&[1.0, 1.0, 0.0], &dir).q_um[0];
    }
    nanocal_bench_stop(6);

    hprintln!("bench done (N = {}, checksum {})", N, acc);
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
