//! The management frame decoder: resynchronisation on garbage, false syncs and cut frames, and
//! the timeout that drops a frame which stopped arriving (issue 21, item 8).

use nanocal_interface::mgmt::{
    self, Decoder, FrameError, Kind, Request, FRAME_TIMEOUT_MS, MAX_FRAME,
};
use proptest::prelude::*;

/// A decoded frame, or why one was dropped.
type Event = Result<(u8, u8, Vec<u8>), FrameError>;

/// Every event after feeding `bytes` at `now_ms` (draining after each byte, as the firmware
/// does).
fn feed_all(d: &mut Decoder, bytes: &[u8], now_ms: u32) -> Vec<Event> {
    let mut out = vec![];
    for &b in bytes {
        let mut ev = d.feed(b, now_ms);
        while let Some(e) = ev {
            out.push(e.map(|()| {
                let f = d.frame();
                (f.kind, f.seq, f.payload.to_vec())
            }));
            ev = d.next(now_ms);
        }
    }
    out
}

/// Every event of calling `next` at `now_ms` until it has none.
fn drain(d: &mut Decoder, now_ms: u32) -> Vec<Event> {
    let mut out = vec![];
    while let Some(e) = d.next(now_ms) {
        out.push(e.map(|()| {
            let f = d.frame();
            (f.kind, f.seq, f.payload.to_vec())
        }));
    }
    out
}

fn frame(kind: u8, seq: u8, payload: &[u8]) -> Vec<u8> {
    let mut b = [0u8; MAX_FRAME];
    let n = mgmt::encode(kind, seq, payload, &mut b).unwrap();
    b[..n].to_vec()
}

fn status(seq: u8) -> Vec<u8> {
    frame(Kind::Status.code(), seq, &[])
}

fn ok_status(seq: u8) -> Event {
    Ok((Kind::Status.code(), seq, vec![]))
}

/// The first 26 bytes of an `UPLOAD_CHUNK` frame announcing 260 payload bytes (offset and 256
/// blob bytes): the frame the connection closed in the middle of.
fn cut_chunk() -> Vec<u8> {
    let blob = [0x5Au8; 256];
    let req = Request::UploadChunk {
        offset: 0,
        bytes: &blob,
    };
    let mut b = [0u8; MAX_FRAME];
    let n = req.frame(9, &mut b).unwrap();
    assert_eq!(u16::from_le_bytes([b[4], b[5]]), 260);
    b[..n.min(26)].to_vec()
}

#[test]
fn garbage_before_a_sync_is_skipped() {
    let mut d = Decoder::new();
    // lone sync halves, a doubled first sync byte, a sync byte at the very end of the garbage
    let mut wire = vec![0x00, 0x5C, 0xA7, 0x00, 0xA7, 0xA7, 0x13, 0xFF, 0xA7];
    wire.extend(status(1));
    wire.extend([0x5C, 0x5C, 0xA7, 0xA7]);
    wire.extend(status(2));
    assert_eq!(feed_all(&mut d, &wire, 0), vec![ok_status(1), ok_status(2)]);
    assert_eq!(d.wait_ms(0), None, "nothing held after the last frame");
}

#[test]
fn a_sync_inside_a_payload_is_not_a_frame_start() {
    let mut d = Decoder::new();
    let payload = [0xA7, 0x5C, 0x02, 0x01, 0x00, 0x00, 0xA7, 0x5C];
    let mut wire = frame(Kind::UploadChunk.code(), 3, &payload);
    wire.extend(status(4));
    assert_eq!(
        feed_all(&mut d, &wire, 0),
        vec![
            Ok((Kind::UploadChunk.code(), 3, payload.to_vec())),
            ok_status(4)
        ]
    );
}

#[test]
fn a_false_sync_announcing_a_long_frame_does_not_swallow_the_frames_after_it() {
    // the cut frame's header announces 260 bytes; 25 status requests follow at once and
    // complete its length: its CRC fails and the requests inside it are found again
    let mut d = Decoder::new();
    let mut wire = cut_chunk();
    for seq in 0..25 {
        wire.extend(status(seq));
    }
    let got = feed_all(&mut d, &wire, 0);
    let mut want = vec![Err(FrameError::BadCrc)];
    want.extend((0..25).map(ok_status));
    assert_eq!(got, want);
}

#[test]
fn a_cut_frame_is_dropped_at_its_timeout_and_the_request_after_it_answered() {
    // the scenario: 26 bytes of a chunk frame, then (a new connection) a status
    // request 10 ms later, then nothing
    let mut d = Decoder::new();
    assert_eq!(feed_all(&mut d, &cut_chunk(), 1000), vec![]);
    assert_eq!(d.wait_ms(1000), Some(FRAME_TIMEOUT_MS));
    assert_eq!(feed_all(&mut d, &status(1), 1010), vec![]);
    assert_eq!(d.wait_ms(1010), Some(FRAME_TIMEOUT_MS - 10));
    // not before its time
    assert_eq!(drain(&mut d, 1000 + FRAME_TIMEOUT_MS - 1), vec![]);
    assert_eq!(
        drain(&mut d, 1000 + FRAME_TIMEOUT_MS),
        vec![Err(FrameError::Timeout), ok_status(1)]
    );
    assert_eq!(d.wait_ms(1000 + FRAME_TIMEOUT_MS), None);
}

#[test]
fn a_request_after_the_timeout_starts_afresh() {
    let mut d = Decoder::new();
    assert_eq!(feed_all(&mut d, &cut_chunk(), 5), vec![]);
    // nobody called next at the deadline: the first byte after it ends the cut frame
    let later = 5 + FRAME_TIMEOUT_MS + 2000;
    assert_eq!(
        feed_all(&mut d, &status(7), later),
        vec![Err(FrameError::Timeout), ok_status(7)]
    );
}

#[test]
fn truncated_frames_of_every_length_are_dropped_and_the_next_frame_decoded() {
    let whole = frame(Kind::UploadChunk.code(), 1, &[1, 2, 3, 4, 5, 6, 7, 8]);
    for cut in 1..whole.len() {
        let mut d = Decoder::new();
        assert_eq!(feed_all(&mut d, &whole[..cut], 0), vec![], "cut at {cut}");
        let got = feed_all(&mut d, &status(2), FRAME_TIMEOUT_MS);
        assert_eq!(
            got,
            vec![Err(FrameError::Timeout), ok_status(2)],
            "cut at {cut}"
        );
    }
}

#[test]
fn a_frame_that_trickles_in_within_its_time_is_taken() {
    let mut d = Decoder::new();
    let wire = frame(Kind::Bypass.code(), 5, &[1]);
    let mut got = vec![];
    for (i, &b) in wire.iter().enumerate() {
        // the last byte arrives just before the frame's time is up
        let t = 100 + (i as u32 * (FRAME_TIMEOUT_MS - 1)) / (wire.len() as u32 - 1);
        got.extend(feed_all(&mut d, &[b], t));
    }
    assert_eq!(got, vec![Ok((Kind::Bypass.code(), 5, vec![1]))]);
}

#[test]
fn a_length_beyond_the_maximum_resynchronises_at_once() {
    let mut d = Decoder::new();
    let mut wire = vec![0xA7, 0x5C, 0x02, 0x00, 0xFF, 0xFF];
    wire.extend(status(3));
    assert_eq!(
        feed_all(&mut d, &wire, 0),
        vec![Err(FrameError::TooLong), ok_status(3)]
    );
}

#[test]
fn clear_forgets_a_half_frame() {
    let mut d = Decoder::new();
    feed_all(&mut d, &cut_chunk(), 0);
    d.clear();
    assert_eq!(d.wait_ms(0), None);
    assert_eq!(feed_all(&mut d, &status(1), 1), vec![ok_status(1)]);
}

#[test]
fn the_clock_may_wrap() {
    let mut d = Decoder::new();
    let t0 = u32::MAX - 100;
    feed_all(&mut d, &cut_chunk(), t0);
    assert_eq!(
        d.wait_ms(t0.wrapping_add(200)),
        Some(FRAME_TIMEOUT_MS - 200)
    );
    assert_eq!(
        drain(&mut d, t0.wrapping_add(FRAME_TIMEOUT_MS)),
        vec![Err(FrameError::Timeout)]
    );
}

#[test]
fn events_left_undrained_are_dropped_not_corrupting() {
    // a caller that reads only the first event of each byte (as a careless host would)
    let mut d = Decoder::new();
    let mut wire = cut_chunk();
    for seq in 0..25 {
        wire.extend(status(seq));
    }
    let first: Vec<_> = wire.iter().filter_map(|&b| d.feed(b, 0)).collect();
    // the byte that completed the false frame's length (the 5th of the last request) reported
    // its CRC; the 24 whole requests found again after it were never asked for and are dropped
    // by the next feed; the last request, still arriving then, is decoded
    assert_eq!(first, vec![Err(FrameError::BadCrc), Ok(())]);
    // later frames still decode
    assert_eq!(feed_all(&mut d, &status(3), 0), vec![ok_status(3)]);
}

fn any_frame() -> impl Strategy<Value = Vec<u8>> {
    (
        any::<u8>(),
        any::<u8>(),
        proptest::collection::vec(any::<u8>(), 0..=mgmt::MAX_PAYLOAD),
    )
        .prop_map(|(k, s, p)| frame(k, s, &p))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(500))]

    /// Valid frames with any garbage between them — false syncs, cut frames, bytes that look
    /// like headers — are all decoded, in order, once the garbage's cut frames time out.
    #[test]
    fn every_frame_survives_any_garbage_around_it(
        parts in proptest::collection::vec(
            (proptest::collection::vec(any::<u8>(), 0..40), any::<bool>(), any_frame()),
            1..8,
        ),
    ) {
        let mut d = Decoder::new();
        let mut got = vec![];
        let mut want = vec![];
        let mut now = 0u32;
        for (garbage, cut_header, f) in &parts {
            let mut junk = garbage.clone();
            if *cut_header {
                // a header announcing a long frame, as a connection closed mid-frame leaves
                junk.extend([0xA7, 0x5C, 0x11, 0x00, 0x04, 0x01]);
            }
            got.extend(feed_all(&mut d, &junk, now));
            got.extend(feed_all(&mut d, f, now));
            want.push((f[2], f[3], f[6..f.len() - 4].to_vec()));
            now += 1;
        }
        // the time of any frame still arriving runs out
        for _ in 0..10_000 {
            if d.wait_ms(now).is_none() {
                break;
            }
            now += FRAME_TIMEOUT_MS;
            got.extend(drain(&mut d, now));
        }
        prop_assert_eq!(d.wait_ms(now), None);
        let frames: Vec<_> = got.into_iter().filter_map(Result::ok).collect();
        prop_assert_eq!(frames, want);
    }
}
