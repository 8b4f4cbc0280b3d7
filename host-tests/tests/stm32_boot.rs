//! The shipped STM32 image boots on the emulated B-L475E-IOT01A (issue 16).
//!
//! Defect 1 (the blocker): with `RCC_CCIPR.ADCSEL = 00` ("no clock selected", RM0351 §6.4.28)
//! and the ADC's synchronous clock off (`ADC_CCR.CKMODE = 00`), `Adc::new` sets ADCAL and spins
//! until the hardware clears it, which an unclocked ADC never does; the watchdog, already
//! running, resets the board every 2 s and the tasks never start. The firmware selects SYSCLK
//! as the ADC's kernel clock (`config()` in src/stm32/clocks.rs).

mod stm32_sim;

use nanocal_stm32_board::ResetKind;
use stm32_sim::Stm32;

#[test]
fn stm32_boots_past_adc_calibration_without_watchdog_resets() {
    let board = Stm32::bare();
    board.usb.attach();
    // 5 s of board time: two watchdog periods. The supervisor task flashes LD2 ("no model":
    // a short flash every 2 s) only once main has spawned the tasks.
    let s = board.run_for(5.0);
    let resets: Vec<_> = s.boots.iter().skip(1).collect();
    assert!(
        resets.is_empty(),
        "the board reset during boot ({resets:?}); it was last at {} — an ADC without a \
         kernel clock never finishes its calibration (ADCAL stays set)",
        s.pc
    );
    assert_eq!(s.boots[0].kind, ResetKind::PowerOn);
    assert!(
        s.led_rises >= 1,
        "LD2 never lit: the supervisor task never ran (board at {})",
        s.pc
    );
    // and the host enumerated it: two CDC-ACM functions, the identity strings
    board.usb.with(|h| {
        assert!(h.errors.is_empty(), "{:?}", h.errors);
        assert!(
            h.configured,
            "not configured; stalls {:?}; host {}",
            h.stalls, h.state
        );
        assert_eq!(h.enumerations, 1);
        assert_eq!(
            &h.device_descriptor[8..12],
            &[0x09, 0x12, 0x01, 0x00],
            "VID 1209 PID 0001"
        );
        let texts: Vec<&str> = h.strings.iter().map(|(_, t)| t.as_str()).collect();
        assert!(texts.contains(&"nanocal inline compensator"), "{texts:?}");
    });
}
