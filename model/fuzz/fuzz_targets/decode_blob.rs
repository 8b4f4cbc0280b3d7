//! Longer runs of the blob decoder than the property tests do: `cargo +nightly fuzz run decode_blob`
//! from `model/`. Whatever the bytes, decoding must not panic, and whatever decodes must
//! re-encode to the same bytes and fold.
#![no_main]

use libfuzzer_sys::fuzz_target;
use nanocal_model::blob::{decode, encode, MAX_BLOB_LEN};

fuzz_target!(|bytes: &[u8]| {
    if let Ok(model) = decode(bytes) {
        let mut out = [0u8; MAX_BLOB_LEN];
        let n = encode(&model, &mut out).expect("a decoded model always encodes");
        assert_eq!(&out[..n], bytes, "decode/encode is not a round trip");
        let _ = model.fold(&Default::default());
    }
});
