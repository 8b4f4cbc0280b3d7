//! `cargo fuzz run gcs_proxy --sanitizer none` from `fuzz/`: the check is [`nanocal_fuzz::checks::gcs_proxy`].
#![no_main]

libfuzzer_sys::fuzz_target!(|bytes: &[u8]| nanocal_fuzz::checks::gcs_proxy(bytes));
