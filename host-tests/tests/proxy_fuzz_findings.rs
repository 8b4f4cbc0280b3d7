//! What the `gcs_proxy` fuzz target (`fuzz/`) found in the GCS proxy, each as the input that
//! showed it, against the target's own model and controller (`fuzz/src/checks.rs`: the model
//! corrects every target by +1000 µm, so an uncorrected move cannot hide). The control-byte
//! findings are issue 21's item 4: such a line is refused (9011), never forwarded.

mod proxy_rig;

#[path = "../../fuzz/src/checks.rs"]
#[allow(dead_code)]
mod checks;

use nanocal::virtual_bench::Event;

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
