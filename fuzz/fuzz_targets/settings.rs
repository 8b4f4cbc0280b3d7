//! `cargo fuzz run settings --sanitizer none` from `fuzz/`: the check is [`nanocal_fuzz::checks::settings`].
#![no_main]

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| nanocal_fuzz::checks::settings(bytes));
