//! Where a model comes from: the stage it was fitted on, when, and from which data (blob
//! format version 4, [`crate::blob`]).
//!
//! The stage is named by its controller's serial number, read from the controller's
//! identification (`*IDN?`). PI's GCS 2.0 commands manuals (e.g. E-727 PZ233E, C-867
//! MS205E, "`*IDN?` (Get Device Identification)") give the reply as
//! `(c)2015 Physik Instrumente (PI) GmbH & Co. KG, E-727, 0116044408, 13.21.00.09`:
//! copyright and company, controller model, serial number, firmware version — the IEEE 488.2
//! §10.14 layout of `*IDN?` (manufacturer, model, serial, firmware) with PI's copyright in the
//! first field. The rule used on both sides of the wire ([`serial_of_idn`]): the serial is the
//! third comma-separated field, spaces (and a CR) around it trimmed. A line with fewer than
//! three fields, or whose third field is empty, longer than [`MAX_SERIAL`] bytes or holds a
//! byte outside printable ASCII, has no serial.
//!
//! The hash of the training data is the 64-bit FNV-1a ([`fnv1a64`]) of the recording file's
//! bytes as the fit read them: it names the data, it does not protect it (FNV is no
//! cryptographic hash).

/// Longest stage serial a blob records (PI's are 9–10 digits).
pub const MAX_SERIAL: usize = 24;
/// Longest axis name a blob records (the recording's `cmd_<axis>` name; a GCS axis
/// identifier has at most 8 characters too).
pub const MAX_AXIS_NAME: usize = 8;

/// Up to `N` ASCII bytes held inline (no heap): the storage of [`StageSerial`] and
/// [`AxisName`], which each check their own rule before they hold any.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
struct ShortAscii<const N: usize> {
    bytes: [u8; N],
    len: u8,
}

impl<const N: usize> ShortAscii<N> {
    /// `text`, already checked: ASCII and at most `N` bytes.
    fn holding(text: &[u8]) -> Self {
        let mut bytes = [0; N];
        bytes[..text.len()].copy_from_slice(text);
        Self {
            bytes,
            len: text.len() as u8,
        }
    }

    fn as_bytes(&self) -> &[u8] {
        &self.bytes[..self.len as usize]
    }

    fn as_str(&self) -> &str {
        core::str::from_utf8(self.as_bytes()).unwrap_or("")
    }
}

/// A stage serial: 1 to [`MAX_SERIAL`] printable ASCII bytes without a comma, not starting or
/// ending with a space.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct StageSerial(ShortAscii<MAX_SERIAL>);

impl StageSerial {
    /// The serial `text`, when it is one (see the type).
    pub fn new(text: &[u8]) -> Option<Self> {
        let ok = !text.is_empty()
            && text.len() <= MAX_SERIAL
            && text
                .iter()
                .all(|&b| (0x20..=0x7E).contains(&b) && b != b',')
            && text[0] != b' '
            && text[text.len() - 1] != b' ';
        ok.then(|| Self(ShortAscii::holding(text)))
    }

    /// The serial's bytes.
    pub fn as_bytes(&self) -> &[u8] {
        self.0.as_bytes()
    }

    /// The serial as text (always ASCII).
    pub fn as_str(&self) -> &str {
        self.0.as_str()
    }
}

impl core::fmt::Debug for StageSerial {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "StageSerial({:?})", self.as_str())
    }
}

impl core::fmt::Display for StageSerial {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// The serial in an identification line (`*IDN?`'s reply, with or without its LF): the third
/// comma-separated field, trimmed (see the module); `None` when it has none.
pub fn serial_of_idn(line: &[u8]) -> Option<StageSerial> {
    let line = line.strip_suffix(b"\n").unwrap_or(line);
    let line = line.strip_suffix(b"\r").unwrap_or(line);
    let field = line.split(|&b| b == b',').nth(2)?;
    let start = field.iter().position(|&b| b != b' ')?;
    let end = field.iter().rposition(|&b| b != b' ')? + 1;
    StageSerial::new(&field[start..end])
}

/// An axis name as the recording spelt it (1 to [`MAX_AXIS_NAME`] printable ASCII bytes).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct AxisName(ShortAscii<MAX_AXIS_NAME>);

impl AxisName {
    /// The name `text`, when it is one.
    pub fn new(text: &[u8]) -> Option<Self> {
        let ok = !text.is_empty()
            && text.len() <= MAX_AXIS_NAME
            && text.iter().all(|&b| (0x21..=0x7E).contains(&b));
        ok.then(|| Self(ShortAscii::holding(text)))
    }

    /// The name's bytes.
    pub fn as_bytes(&self) -> &[u8] {
        self.0.as_bytes()
    }

    /// The name as text (always ASCII).
    pub fn as_str(&self) -> &str {
        self.0.as_str()
    }
}

impl core::fmt::Debug for AxisName {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "AxisName({:?})", self.as_str())
    }
}

/// The unit the fit's positions were in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ProvenanceUnit {
    /// Not recorded.
    #[default]
    Unknown,
    /// Micrometres (the recording layout's and the model's unit).
    Um,
}

impl ProvenanceUnit {
    /// The blob's code (0 unknown, 1 µm).
    pub const fn code(self) -> u8 {
        match self {
            ProvenanceUnit::Unknown => 0,
            ProvenanceUnit::Um => 1,
        }
    }
    /// The unit of a code.
    pub const fn from_code(c: u8) -> Option<Self> {
        match c {
            0 => Some(ProvenanceUnit::Unknown),
            1 => Some(ProvenanceUnit::Um),
            _ => None,
        }
    }
    /// The unit's name.
    pub const fn name(self) -> &'static str {
        match self {
            ProvenanceUnit::Unknown => "unknown",
            ProvenanceUnit::Um => "µm",
        }
    }
}

/// Where a model comes from. Every field may be unknown: a version 1–3 blob has none, and a
/// fit told nothing of the stage records no serial (the device then checks nothing).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Provenance {
    /// The serial of the controller the stage was fitted on (`None`: unknown, no check).
    pub stage_serial: Option<StageSerial>,
    /// The model axes' names in the recording, in model axis order (`None` past the model's
    /// axes, or not recorded).
    pub axes: [Option<AxisName>; crate::MAX_AXES],
    /// The unit of the fitted positions.
    pub unit: ProvenanceUnit,
    /// When the fit ran, UTC seconds since 1970-01-01 (0: unknown).
    pub fit_date_s: i64,
    /// 64-bit FNV-1a of the training recording's bytes ([`fnv1a64`]; 0: unknown).
    pub data_fnv64: u64,
}

impl Provenance {
    /// Nothing known (what a version 1–3 blob decodes to).
    pub const UNKNOWN: Provenance = Provenance {
        stage_serial: None,
        axes: [None; crate::MAX_AXES],
        unit: ProvenanceUnit::Unknown,
        fit_date_s: 0,
        data_fnv64: 0,
    };

    /// True when nothing is known.
    pub fn is_unknown(&self) -> bool {
        *self == Provenance::UNKNOWN
    }
}

/// 64-bit FNV-1a (offset basis 0xcbf29ce484222325, prime 0x100000001b3): the hash of a
/// fit's training data.
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pi_identification_gives_its_serial() {
        let s = serial_of_idn(
            b"(c)2015 Physik Instrumente (PI) GmbH & Co. KG, E-727, 0116044408, 13.21.00.09\n",
        )
        .unwrap();
        assert_eq!(s.as_bytes(), b"0116044408");
        let s = serial_of_idn(b"PI, C-867,  117012345 ,01.00\r\n").unwrap();
        assert_eq!(s.as_str(), "117012345");
    }

    #[test]
    fn lines_without_a_serial_have_none() {
        for line in [
            &b""[..],
            b"PI E-727 0116044408",
            b"PI, E-727",
            b"PI, E-727, , 1.0",
            b"PI, E-727,    ",
            b"PI, E-727, 0123456789012345678901234, 1.0",
            b"PI, E-727, 01\x0123, 1.0",
        ] {
            assert_eq!(serial_of_idn(line), None, "{line:?}");
        }
    }

    #[test]
    fn fnv1a64_matches_the_published_test_vectors() {
        // Fowler/Noll/Vo test vectors (draft-eastlake-fnv, FNV-1a 64)
        assert_eq!(fnv1a64(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a64(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a64(b"foobar"), 0x8594_4171_f739_67e8);
    }
}
