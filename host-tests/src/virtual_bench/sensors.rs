//! Simulated temperature-amplifier chips behind the QEMU board's serial sensor bus.

use nanocal_compensator::sensor::{self, bus, FRAME_LEN};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::sync::{Arc, Mutex};

/// Simulated MAX31856 chips on the sensor-bus stand-in.
pub struct SensorSim {
    state: Arc<Mutex<(Vec<f32>, Vec<u8>)>>,
}

impl SensorSim {
    /// Serve `s` with the given temperatures on chip-selects 0.. .
    pub fn start(s: TcpStream, temps: &[f32]) -> Self {
        let state = Arc::new(Mutex::new((temps.to_vec(), vec![0u8; temps.len()])));
        let st = state.clone();
        std::thread::spawn(move || {
            let mut r = s.try_clone().unwrap();
            let mut w = s;
            let mut buf: Vec<u8> = Vec::new();
            let mut b = [0u8; 256];
            loop {
                let n = match r.read(&mut b) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => n,
                };
                buf.extend_from_slice(&b[..n]);
                loop {
                    while !buf.is_empty() && buf[0] != bus::REQ {
                        buf.remove(0);
                    }
                    if buf.len() < bus::WIRE_LEN {
                        break;
                    }
                    let req: Vec<u8> = buf.drain(..bus::WIRE_LEN).collect();
                    let cs = req[1];
                    let tx = &req[3..];
                    let data: [u8; FRAME_LEN] = {
                        let s = st.lock().unwrap();
                        match s.0.get(cs as usize) {
                            Some(&t) if tx[0] == sensor::max31856::READ_FROM => {
                                sensor::encode_max31856(t, 25.0, s.1[cs as usize])
                            }
                            Some(_) => [0xFF; FRAME_LEN], // configuration write
                            None => continue,             // no chip: no answer
                        }
                    };
                    let mut rep = vec![bus::REP, cs, FRAME_LEN as u8];
                    rep.extend_from_slice(&data);
                    if w.write_all(&rep).is_err() {
                        return;
                    }
                }
            }
        });
        Self { state }
    }

    /// Set the status register (fault bits) of chip `cs`.
    pub fn set_status(&self, cs: usize, sr: u8) {
        self.state.lock().unwrap().1[cs] = sr;
    }

    /// Set the temperature of chip `cs`.
    pub fn set_temp(&self, cs: usize, t: f32) {
        self.state.lock().unwrap().0[cs] = t;
    }
}
