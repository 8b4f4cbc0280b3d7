//! `cargo fuzz run blob --sanitizer none` from `fuzz/`: the check is [`nanocal_fuzz::checks::blob`].
#![no_main]

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| nanocal_fuzz::checks::blob(bytes));
