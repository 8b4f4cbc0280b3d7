//! Every decoder of outside bytes returns a value or an error, never panics, on any input; and
//! what a decoder accepts encodes back to the same bytes.

use nanocal_interface::bus::{BusReply, BusRequest};
use nanocal_interface::mgmt::{Decoder, Kind, Reader, Reply, Request, Writer, MAX_FRAME};
use nanocal_interface::settings::Settings;
use nanocal_interface::status::Status;
use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4000))]

    #[test]
    fn requests_decode_or_refuse(kind in any::<u8>(), payload in proptest::collection::vec(any::<u8>(), 0..300)) {
        if let Ok(req) = Request::decode(kind, &payload) {
            prop_assert_eq!(req.kind().code(), kind);
            let mut out = [0u8; MAX_FRAME];
            prop_assert!(req.frame(0, &mut out).is_ok());
        }
    }

    #[test]
    fn replies_decode_or_refuse(k in 0..Kind::ALL.len(), payload in proptest::collection::vec(any::<u8>(), 0..300)) {
        if let Ok(reply) = Reply::decode(Kind::ALL[k], &payload) {
            let mut out = [0u8; 400];
            let mut w = Writer::new(&mut out);
            prop_assert!(reply.encode(&mut w).is_ok());
        }
    }

    #[test]
    fn status_decodes_or_refuses(b in proptest::collection::vec(any::<u8>(), 0..260)) {
        if let Ok(s) = Status::decode(&mut Reader::new(&b)) {
            let mut out = [0u8; Status::LEN];
            let mut w = Writer::new(&mut out);
            s.encode(&mut w).unwrap();
            // the reserved byte is written as 0xFF whatever came in
            let mut want = b[..Status::LEN].to_vec();
            want[6] = 0xFF;
            prop_assert_eq!(&out[..], &want[..]);
        }
    }

    #[test]
    fn settings_decode_or_refuse(b in proptest::collection::vec(any::<u8>(), 0..260)) {
        let _ = Settings::decode(&b);
    }

    #[test]
    fn bus_frames_decode_or_refuse(b in proptest::collection::vec(any::<u8>(), 0..48)) {
        let _ = BusRequest::decode(&b);
        let _ = BusReply::decode(&b);
    }

    #[test]
    fn frame_decoder_takes_any_bytes(b in proptest::collection::vec(any::<u8>(), 0..2000)) {
        let mut d = Decoder::new();
        for (i, &x) in b.iter().enumerate() {
            // a clock that jumps now and then, so that timeouts happen too
            let now = (i as u32 / 97) * 300;
            let mut ev = d.feed(x, now);
            while let Some(e) = ev {
                if e.is_ok() {
                    let f = d.frame();
                    prop_assert!(f.payload.len() <= nanocal_interface::mgmt::MAX_PAYLOAD);
                }
                ev = d.next(now);
            }
        }
    }
}

/// Valid settings with random bytes changed: refused or decoded, never a panic (random bytes
/// alone almost never get past the magic and the CRC).
#[test]
fn mutated_settings_with_a_fixed_crc() {
    let good = Settings::default().encode();
    let mut rng = 0x2545_F491_4F6C_DD1Du64;
    for _ in 0..20_000 {
        let mut b = good;
        for _ in 0..3 {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            let at = 5 + (rng % (b.len() as u64 - 9)) as usize;
            b[at] = (rng >> 32) as u8;
        }
        let n = b.len() - 4;
        let crc = nanocal_interface::crc32(&b[..n]);
        b[n..].copy_from_slice(&crc.to_le_bytes());
        if let Ok(s) = Settings::decode(&b) {
            // a stored record may hold a baud rate of a firmware with other limits
            assert!(s.validate_stored().is_ok());
        }
    }
}
