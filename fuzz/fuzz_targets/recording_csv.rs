//! `cargo fuzz run recording_csv --sanitizer none` from `fuzz/`: the check is [`nanocal_fuzz::checks::recording_csv`].
#![no_main]

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| nanocal_fuzz::checks::recording_csv(bytes));
