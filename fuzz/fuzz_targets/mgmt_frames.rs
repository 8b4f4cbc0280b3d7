//! `cargo fuzz run mgmt_frames --sanitizer none` from `fuzz/`: the check is [`nanocal_fuzz::checks::mgmt_frames`].
#![no_main]

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| nanocal_fuzz::checks::mgmt_frames(bytes));
