//! What the fuzz's host sends: valid GCS lines in every spelling, the same lines mutated
//! (a byte inserted, removed, a case flipped, a prefix, a CR), hostile lines (control
//! characters that hide a command, overlong lines, floods), single characters.

use rand::seq::SliceRandom;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// The host's generator.
pub(super) struct Gen {
    /// Model axes.
    n: usize,
    /// Values span (µm): the model's training range.
    span: f64,
}

const QUERIES: &[&str] = &[
    "POS?", "POS?", "POS?", "MOV?", "MOV?", "ERR?", "ERR?", "ONT?", "SVO?", "*IDN?", "CSV?",
    "PUN?", "TMN?", "TMX?", "SAI?", "VEL?", "FOO?", "FRF?",
];

const STOPS: &[&str] = &["HLT", "HLT", "STP", "FRF", "FNL", "FPL"];

const RAW: &[&str] = &[
    "STE 1 5",
    "SVA 1 10",
    "IMP 1 1",
    "SMO 1 100",
    "WGO 1 1",
    "WGO 1 0",
    "WAV 1 X LIN 100 20 0 100 0 0",
    "MAC START m",
    "MAC STOP",
    "POS 1 3",
    "DFH 1",
    "SAI 1 X",
    "STE 3 5",
    "VEL 1 2000",
    "VEL 3 10",
    "MOV 3 20",
    "MVR 3 1",
    "CCL 1 advanced",
    "PUN 1 mm",
    "PUN 1 UM",
    "RON 1 0",
    "BLA 1 2",
];

const HOSTILE: &[&[u8]] = &[
    b"\rMOV 1 200\n",
    b"MOV\r1 300\n",
    b"\rMVR 1 5\n",
    b"\rPOS?\n",
    b"MOV 1 1\x00\n",
    b"MOV 1 \x7f5\n",
    b"MOV\x0c1 7\n",
    b"POS? 1\x1a\n",
    b"MOV 1 10\r\r\n",
    b"PUN 1 \xb5m\n",
    b"mov 1 2\xe9\n",
    b"\n",
    b"\r\n",
    b"   \n",
    b"MOV 1 10\rPOS? 1\n",
];

impl Gen {
    pub(super) fn new(n: usize) -> Self {
        Self {
            n,
            span: if n == 1 { 480.0 } else { 80.0 },
        }
    }

    pub(super) fn new_session(&mut self) {}

    /// One item: a line, a few lines, or a single character.
    pub(super) fn item(&mut self, rng: &mut ChaCha8Rng) -> Vec<u8> {
        match rng.gen_range(0..100u32) {
            0..=29 => {
                let l = self.move_line(rng);
                self.spell(rng, &l)
            }
            30..=57 => {
                let l = self.query(rng);
                self.spell(rng, &l)
            }
            58..=63 => {
                let l = self.stop(rng);
                self.spell(rng, &l)
            }
            64..=68 => {
                let l = *RAW.choose(rng).unwrap();
                self.spell(rng, l)
            }
            69..=76 => {
                let b = *[3u8, 3, 4, 5, 5, 6, 7, 8, 9, 11, 0x18, 0x1b]
                    .choose(rng)
                    .unwrap();
                if b >= 0x18 && rng.gen_bool(0.7) {
                    // stops are rarer
                    vec![5]
                } else {
                    vec![b]
                }
            }
            77..=84 => HOSTILE.choose(rng).unwrap().to_vec(),
            85..=94 => {
                let base = match rng.gen_range(0..3) {
                    0 => self.move_line(rng),
                    1 => self.query(rng),
                    _ => self.stop(rng),
                };
                let mut l = self.spell(rng, &base);
                mutate(rng, &mut l);
                l
            }
            95..=96 => {
                // a burst of queries in one write (PIPython's command + ERR?, or a flood)
                let mut v = Vec::new();
                for _ in 0..rng.gen_range(2..6) {
                    let l = self.query(rng);
                    v.extend(self.spell(rng, &l));
                }
                v
            }
            97 => {
                // longer than the proxy's line buffer, or than its input buffer
                let k = if rng.gen_bool(0.5) { 25 } else { 45 };
                format!("SPA? {}\n", "1 0x07000000 ".repeat(k)).into_bytes()
            }
            98 => b"RBT\n".to_vec(),
            _ => {
                // a move with the ERR? PIPython sends after it, in one write
                let l = self.move_line(rng);
                let mut v = self.spell(rng, &l);
                v.extend(self.spell(rng, "ERR?"));
                v
            }
        }
    }

    fn axis(&self, rng: &mut ChaCha8Rng) -> &'static str {
        match rng.gen_range(0..20u32) {
            0..=11 => "1",
            12..=15 => {
                if self.n > 1 {
                    "2"
                } else {
                    "3"
                }
            }
            16..=17 => "3",
            18 => "2",
            _ => ["5", "A", "x"].choose(rng).unwrap(),
        }
    }

    fn value(&self, rng: &mut ChaCha8Rng, relative: bool) -> String {
        let v: f64 = if relative {
            match rng.gen_range(0..10u32) {
                0 => rng.gen_range(-200.0..200.0),
                _ => rng.gen_range(-20.0..20.0),
            }
        } else {
            match rng.gen_range(0..20u32) {
                0 => 0.0,
                1 => self.span,
                2 => rng.gen_range(-40.0..0.0),
                3 => rng.gen_range(self.span..self.span + 60.0),
                _ => rng.gen_range(0.0..self.span),
            }
        };
        match rng.gen_range(0..4u32) {
            0 => format!("{v}"),
            1 => format!("{v:.0}"),
            2 => format!("{:.*}", rng.gen_range(1..9), v),
            _ => format!("{v:.3}"),
        }
    }

    fn move_line(&self, rng: &mut ChaCha8Rng) -> String {
        let kind = *["MOV", "MOV", "MOV", "MVR", "MVR", "MVE", "GOH"]
            .choose(rng)
            .unwrap();
        let mut s = kind.to_string();
        if kind == "GOH" {
            for _ in 0..rng.gen_range(0..3) {
                s += " ";
                s += self.axis(rng);
            }
            return s;
        }
        for _ in 0..rng.gen_range(1..4) {
            s += " ";
            s += self.axis(rng);
            s += " ";
            s += &self.value(rng, kind == "MVR");
        }
        s
    }

    fn query(&self, rng: &mut ChaCha8Rng) -> String {
        let q = *QUERIES.choose(rng).unwrap();
        let mut s = q.to_string();
        if matches!(q, "ERR?" | "*IDN?" | "CSV?" | "FOO?") {
            return s;
        }
        if q == "SAI?" {
            if rng.gen_bool(0.3) {
                s += " ALL";
            }
            return s;
        }
        for _ in 0..rng.gen_range(0..3) {
            s += " ";
            s += self.axis(rng);
        }
        s
    }

    fn stop(&self, rng: &mut ChaCha8Rng) -> String {
        match rng.gen_range(0..4u32) {
            0 => {
                let mut s = "SVO".to_string();
                for _ in 0..rng.gen_range(1..3) {
                    s += " ";
                    s += self.axis(rng);
                    s += if rng.gen_bool(0.85) { " 1" } else { " 0" };
                }
                s
            }
            _ => {
                let c = *STOPS.choose(rng).unwrap();
                let mut s = c.to_string();
                if c != "STP" {
                    for _ in 0..rng.gen_range(0..2) {
                        s += " ";
                        s += self.axis(rng);
                    }
                }
                s
            }
        }
    }

    /// A line as a host may spell it: mnemonic case, spaces, an address prefix.
    fn spell(&self, rng: &mut ChaCha8Rng, line: &str) -> Vec<u8> {
        let mut toks: Vec<String> = line.split(' ').map(String::from).collect();
        if rng.gen_bool(0.3) {
            toks[0] = toks[0]
                .chars()
                .map(|c| {
                    if rng.gen_bool(0.5) {
                        c.to_ascii_lowercase()
                    } else {
                        c
                    }
                })
                .collect();
        }
        let mut s = match rng.gen_range(0..40u32) {
            0 => "1 ".to_string(),
            1 => "1 0 ".to_string(),
            2 => "2 ".to_string(),
            _ => String::new(),
        };
        for (i, t) in toks.iter().enumerate() {
            if i > 0 {
                s += if rng.gen_bool(0.1) { "  " } else { " " };
            }
            s += t;
        }
        if rng.gen_bool(0.05) {
            s.push('\r');
        }
        s.push('\n');
        s.into_bytes()
    }
}

/// A byte inserted (any value, single-character commands and LF among them), removed or
/// changed in a line.
fn mutate(rng: &mut ChaCha8Rng, l: &mut Vec<u8>) {
    let body = l.len().saturating_sub(1).max(1);
    match rng.gen_range(0..4u32) {
        0 | 1 => {
            let at = rng.gen_range(0..body);
            let b = if rng.gen_bool(0.5) {
                rng.gen_range(0..0x20u8)
            } else {
                rng.gen()
            };
            l.insert(at, b);
        }
        2 => {
            let at = rng.gen_range(0..body);
            if at < l.len() - 1 {
                l.remove(at);
            }
        }
        _ => {
            let at = rng.gen_range(0..body);
            l[at] = rng.gen_range(0x20..0x7F);
        }
    }
    if l.last() != Some(&b'\n') {
        l.push(b'\n');
    }
}
