//! Longer runs of the blob decoder than the property tests do: `cargo +nightly fuzz run decode_blob`
//! from `model/`. Whatever the bytes, decoding must not panic; whatever decodes must re-encode
//! to the same bytes (a version 1 blob: to a version 2 blob of the same model), fold, and run
//! the fast path and the inverse without panicking.
#![no_main]

use libfuzzer_sys::fuzz_target;
use nanocal_model::blob::{decode, encode, FORMAT_VERSION, MAX_BLOB_LEN};
use nanocal_model::{FastInputs, HysteresisState};

fuzz_target!(|bytes: &[u8]| {
    if let Ok(model) = decode(bytes) {
        let mut out = [0u8; MAX_BLOB_LEN];
        let n = encode(&model, &mut out).expect("a decoded model always encodes");
        if bytes[4..6] == FORMAT_VERSION.to_le_bytes() {
            assert_eq!(&out[..n], bytes, "decode/encode is not a round trip");
        } else {
            assert_eq!(decode(&out[..n]).as_ref(), Ok(&model), "v1 → v2 changed the model");
        }
        let fold = model.fold(&Default::default());
        let mut state = HysteresisState::new();
        let fast = FastInputs::NONE.with_aux(0, 0.25);
        for x in [1.0f32, 7.5, 3.0] {
            let c = fold.correct(&[x, -x, x], &[1, 0, -1], &fast, &mut state);
            let _ = fold.inverse(&c.q_um, &[1, 0, -1], &fast, &state);
        }
    }
});
