use nanocal_stm32_board::*;
use std::sync::{Arc, Mutex};

#[test]
fn boots() {
    let elf = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../target/thumbv7em-none-eabihf/release/nanocal-fw"
    ))
    .unwrap();
    let io = Io::new(Arc::new(Mutex::new(NoChips)), None, usb::Host::default());
    let control = Control::default();
    let c2 = control.clone();
    let stop = control.stop.clone();
    let mut b = Board::new(&elf, None, io, control).unwrap();
    std::thread::spawn(move || {
        std::thread::sleep(std::time::Duration::from_secs(14));
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
    });
    let h = b.run();
    let st = b_status(&c2);
    eprintln!("halt {h:?}\n{st:#x?}");
}

fn b_status(c: &Control) -> Status {
    c.status.lock().unwrap().clone()
}
