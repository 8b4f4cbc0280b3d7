//! What the `gcs_proxy` fuzz target (`fuzz/`) found in the GCS proxy, each as the input that
//! showed it, against the target's own model and controller (`fuzz/src/checks.rs`: the model
//! corrects every target by +1000 µm, so an uncorrected move cannot hide). The control-byte
//! findings are issue 21's item 4: such a line is refused (9011), never forwarded.

mod proxy_rig;

#[path = "../../fuzz/src/checks.rs"]
#[allow(dead_code)]
mod checks;

use nanocal::virtual_bench::Event;
use nanocal_compensator::proxy::{Output, Proxy};
use proxy_rig::text;

/// Targets the controller accepted on model axis 0 that are not a correction (outside
/// 999…1501 µm), and raw motions, after `bytes` from the host.
fn uncorrected(bytes: &[u8]) -> Vec<Event> {
    let model = checks::proxy_model(1);
    let mut cfg = proxy_rig::everything(2);
    for a in &mut cfg.axes {
        a.max = 2000.0;
        a.reference = Some(1250.0);
        a.start = 1250.0;
    }
    let mut rig = proxy_rig::Rig::new(cfg, Some(&model), &[]);
    rig.host(bytes);
    rig.settle();
    rig.events()
        .into_iter()
        .filter(|e| match e {
            Event::Target { axis: 0, value, .. } => !(999.0..=1501.0).contains(value),
            Event::RawMotion { .. } => true,
            _ => false,
        })
        .collect()
}

#[test]
fn a_plain_move_is_corrected() {
    // the check itself: the same move without the control byte is corrected
    assert_eq!(uncorrected(b"MOV 1 200\n"), vec![]);
}

#[test]
fn a_cr_before_the_command_does_not_hide_it() {
    // fuzz input fuzz/seeds/gcs_proxy/issue-21-cr-hides-mov (dictionary line "\rMOV 1 200"):
    // the controller, which takes CR as white space, moved to exactly 200 µm, uncorrected
    assert_eq!(uncorrected(b"\rMOV 1 200\n"), vec![]);
    assert_eq!(uncorrected(b"MOV\r1 300\n"), vec![]);
}

#[test]
fn a_no_break_space_does_not_hide_a_command() {
    // fuzz input fuzz/seeds/gcs_proxy/issue-21-nbsp-hides-mov: ` \xA0` then `MOV 1 100`; the
    // simulated controller decodes PI's code page, where A0h is a no-break space, white space
    // to it: MOV 1 100 reached it uncorrected
    assert_eq!(uncorrected(b" \xA0MOV 1 100\n"), vec![]);
}

#[test]
fn an_open_loop_command_for_an_axis_the_controller_lacks_is_no_motion() {
    // fuzz input fuzz/seeds/gcs_proxy/sva-invalid-axis (`SVA   HLT`): the proxy relays commands
    // that name no model axis; the simulated controller recorded `SVA HLT` as an open-loop
    // motion of any axis, where a PI controller answers error 15 (invalid axis) and does nothing
    for line in [&b"SVA HLT\n"[..], b"SVA 3 10\n", b"OMA HLT\n"] {
        assert_eq!(
            uncorrected(line),
            vec![],
            "{}",
            String::from_utf8_lossy(line)
        );
    }
    // a model axis is still refused by the proxy, and a relayed axis still reaches the
    // controller as the open-loop command it is
    assert_eq!(uncorrected(b"SVA 1 10\n"), vec![]);
    assert!(matches!(
        &uncorrected(b"SVO 2 0\nSVA 2 10\n")[..],
        [Event::RawMotion { axes, .. }] if axes == &[1]
    ));
}

/// Controller bytes fed to the proxy until it took them all (it stops after a marker it sent,
/// which must be empty here: nothing goes out while it resynchronises); what reached the host.
fn feed_stage(p: &mut Proxy, bytes: &[u8], now_ms: u32) -> Vec<u8> {
    let mut out = Output::new();
    let mut host = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let used = p.stage_bytes(None, &bytes[i..], now_ms, &mut out);
        host.extend_from_slice(out.to_host.as_bytes());
        assert!(
            used > 0 || !out.is_empty(),
            "the proxy took none of {:?}",
            &bytes[i..]
        );
        i += used;
    }
    host
}

/// The proxy fuzz's benchmark (issue 21; on main after the merges: the sparse controller's
/// seed 1018, step 20,585, and the coupled 2-DoF setup's seed 1015, step 19,227): bytes were
/// lost twice, the second time while the proxy was still resynchronising after the first,
/// with identification lines of the queries it had given up still coming. The second
/// resynchronisation counted only the marker under way (the count of stale lines the first
/// one kept was lost), so it ended at a stale identification line, and the replies still due
/// were paired with the next queries: the proxy's own `CSV?` took a position reply (a
/// controller without `CSV?` then counted as answering it), and the host's `pOS?` got the
/// reply of a `CSV?` before it, unmapped. The stale lines still due now carry over: nothing
/// goes out until the last marker's own reply.
#[test]
fn a_second_loss_while_resynchronising_still_waits_for_the_stale_identification_lines() {
    let mut p = Proxy::default();
    let mut out = Output::new();
    // the controller's identification line (what markers bring back), read from the host's
    // `*IDN?`
    p.host_bytes(None, b"*IDN?\n", 1, &mut out);
    assert_eq!(out.to_stage.as_bytes(), b"*IDN?\n");
    assert_eq!(feed_stage(&mut p, b"ID\n", 1), b"ID\n");
    // two queries the controller may leave unanswered: each goes out with a marker
    let mut to_ctl = Vec::new();
    for _ in 0..2 {
        assert_eq!(p.host_bytes(None, b"VEL?\n", 2, &mut out), 5);
        to_ctl.extend_from_slice(out.to_stage.as_bytes());
    }
    assert_eq!(text(&to_ctl), "VEL?\n*IDN?\nVEL?\n*IDN?\n");
    // the controller answers both: `1=5` and its identification line, twice
    let mut due = b"1=5\nID\n1=5\nID\n".to_vec();
    // bytes lost before any of it arrived: the proxy gives up both and resynchronises (two
    // identification lines still due before its marker's)
    p.stage_bytes_lost(3);
    p.poll(None, 3, &mut out);
    assert_eq!(out.to_stage.as_bytes(), b"*IDN?\n");
    due.extend_from_slice(b"ID\n");
    // the replies given up and the first byte of the second stale identification line
    // arrive; the next byte is lost
    assert_eq!(text(&due[..12]), "1=5\nID\n1=5\nI");
    assert_eq!(feed_stage(&mut p, &due[..12], 4), b"");
    p.stage_bytes_lost(4);
    p.poll(None, 5, &mut out);
    assert_eq!(out.to_stage.as_bytes(), b"*IDN?\n");
    // still coming: the damaged line's end and the first marker's reply — then the second
    // marker's
    let rest = [&due[13..], b"ID\n"].concat();
    assert_eq!(text(&rest), "\nID\nID\n");
    let (stale, own) = rest.split_at(rest.len() - 3);
    assert_eq!(feed_stage(&mut p, stale, 6), b"");
    // a host query waits: the marker's own reply has not come yet (before the fix the
    // resynchronisation ended at the first marker's reply, and this query went out)
    assert_eq!(p.host_bytes(None, b"VEL?\n", 7, &mut out), 0);
    assert!(out.is_empty());
    assert_eq!(feed_stage(&mut p, own, 8), b"");
    // resynchronised: the query goes out and gets its own reply
    assert_eq!(p.host_bytes(None, b"VEL?\n", 9, &mut out), 5);
    assert_eq!(out.to_stage.as_bytes(), b"VEL?\n*IDN?\n");
    assert_eq!(feed_stage(&mut p, b"1=5\nID\n", 10), b"1=5\n");
    p.host_bytes(None, b"ERR?\n", 11, &mut out);
    assert_eq!(text(out.to_host.as_bytes()), "9010\n");
}
