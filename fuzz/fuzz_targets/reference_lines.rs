//! `cargo fuzz run reference_lines --sanitizer none` from `fuzz/`: the check is [`nanocal_fuzz::checks::reference_lines`].
#![no_main]

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| nanocal_fuzz::checks::reference_lines(bytes));
