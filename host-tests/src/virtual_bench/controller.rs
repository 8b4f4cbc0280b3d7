//! A simulated PI controller on the stage link (GCS over a byte stream).

use std::collections::HashMap;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::sync::mpsc::{channel, Receiver};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// A simulated PI controller on the stage link: executes MOV at once and answers queries.
pub struct StageSim {
    lines: Receiver<String>,
    /// Axis positions.
    pub pos: Arc<Mutex<HashMap<String, f64>>>,
}

impl StageSim {
    /// Serve `s`, with axes "1".."n".
    pub fn start(s: TcpStream, axes: usize) -> Self {
        let (tx, rx) = channel();
        let pos = Arc::new(Mutex::new(
            (1..=axes)
                .map(|a| (a.to_string(), 0.0))
                .collect::<HashMap<_, _>>(),
        ));
        let p2 = pos.clone();
        std::thread::spawn(move || {
            let mut r = s.try_clone().unwrap();
            let mut w = s;
            let mut line = Vec::new();
            let mut b = [0u8; 512];
            loop {
                let n = match r.read(&mut b) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => n,
                };
                for &c in &b[..n] {
                    if line.is_empty() && nanocal_compensator::gcs::is_single_char_command(c) {
                        if tx.send(format!("#{c}")).is_err() {
                            return;
                        }
                        if c != 0x18 {
                            let _ = w.write_all(b"0\n");
                        }
                        continue;
                    }
                    if c != b'\n' {
                        line.push(c);
                        continue;
                    }
                    let l = String::from_utf8_lossy(&line).into_owned();
                    line.clear();
                    let reply = answer(&l, &p2);
                    // record before replying, so a host that saw the reply sees the record
                    if tx.send(l).is_err() {
                        return;
                    }
                    if let Some(r) = reply {
                        let _ = w.write_all(r.as_bytes());
                    }
                }
            }
        });
        Self { lines: rx, pos }
    }

    /// The next line the controller received.
    pub fn next_line(&self, timeout: Duration) -> String {
        self.lines
            .recv_timeout(timeout)
            .expect("the controller received nothing in time")
    }

    /// Lines received so far, without waiting.
    pub fn drain(&self) -> Vec<String> {
        self.lines.try_iter().collect()
    }
}

fn answer(line: &str, pos: &Mutex<HashMap<String, f64>>) -> Option<String> {
    let t: Vec<&str> = line.split_whitespace().collect();
    let cmd = *t.first()?;
    let mut p = pos.lock().unwrap();
    let axes_reply = |p: &HashMap<String, f64>, args: &[&str], f: &dyn Fn(f64) -> String| {
        let mut axes: Vec<String> = if args.is_empty() {
            let mut k: Vec<String> = p.keys().cloned().collect();
            k.sort();
            k
        } else {
            args.iter().map(|s| s.to_string()).collect()
        };
        axes.retain(|a| p.contains_key(a));
        let n = axes.len();
        let mut out = String::new();
        for (i, a) in axes.iter().enumerate() {
            out += &format!("{a}={}{}\n", f(p[a]), if i + 1 < n { " " } else { "" });
        }
        out
    };
    match cmd {
        "MOV" | "MVR" => {
            for c in t[1..].chunks(2) {
                if let [a, v] = c {
                    if let Ok(v) = v.parse::<f64>() {
                        let e = p.entry(a.to_string()).or_insert(0.0);
                        *e = if cmd == "MVR" { *e + v } else { v };
                    }
                }
            }
            None
        }
        "POS?" | "MOV?" => Some(axes_reply(&p, &t[1..], &|v| format!("{v:.6}"))),
        "ONT?" | "SVO?" | "qONT" => Some(axes_reply(&p, &t[1..], &|_| "1".into())),
        "ERR?" => Some("0\n".into()),
        "*IDN?" => Some(
            "(c)2026 Physik Instrumente (PI) GmbH & Co. KG, E-727, 0, 1.0 (simulated)\n".into(),
        ),
        "SAI?" => {
            let mut k: Vec<String> = p.keys().cloned().collect();
            k.sort();
            let n = k.len();
            Some(
                k.iter()
                    .enumerate()
                    .map(|(i, a)| format!("{a}{}\n", if i + 1 < n { " " } else { "" }))
                    .collect(),
            )
        }
        c if c.ends_with('?') => Some("0\n".into()),
        _ => None,
    }
}
