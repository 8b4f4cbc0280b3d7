//! `cargo fuzz run upload --sanitizer none` from `fuzz/`: the check is [`nanocal_fuzz::checks::upload`].
#![no_main]

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| nanocal_fuzz::checks::upload(bytes));
