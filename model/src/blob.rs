//! The coefficient blob: the only place that knows the bytes of a stored model.
//!
//! All integers and floats are little-endian; floats are IEEE-754 binary64.
//!
//! ```text
//! offset      size  field
//! 0           4     magic "NCAL"
//! 4           2     format version (u16) = FORMAT_VERSION (4)
//! 6           2     reserved, 0
//! 8           4     payload length N (u32)
//! 12          N     payload
//! 12+N        4     CRC-32/IEEE (zlib) of bytes 0 .. 12+N (u32)
//!
//! payload
//! +0          4     model id (u32)
//! +4          1     axes A (1..=3)
//! +5          1     temperatures T (0..=16)
//! +6          1     aux channels X (0..=4)
//! +7          1     lag filters L (0..=32)
//! +8          2     terms K (u16, 0..=128)
//! +10         1     play operators P (0..=48)
//! +11         1     bound mask B: bit a set = output axis a carries a prediction bound
//!                   (bits ≥ A are 0)
//! +12         32·(A+T+X)  per input, axes then temperatures then aux:
//!                   centre f64 | half_range f64 | envelope min f64 | envelope max f64
//! then        16·A  per axis: travel min f64 | travel max f64 (command space, µm)
//! then        16·A  per axis: offset λ f64 | adaptive offset λ_KMZ f64 (µm)
//! then        8·X   per aux input: kind u8 (0 other, 1 air pressure hPa, 2 force N) |
//!                   flags u8 (bit 0: fast, evaluated per command; other bits 0) | 6 reserved, 0
//! then        16·L  per lag: sensor u8 | 7 reserved bytes, 0 | τ f64 (s)
//! then        16·P  per play operator: axis u8 | 7 reserved bytes, 0 | threshold f64 (µm);
//!                   grouped by axis in axis order, thresholds strictly ascending per axis
//! then        16·K  per term: output u8 | power x u8 | power y u8 | power z u8 |
//!                   factor kind u8 (0 none, 1 temp, 2 aux, 3 lagged, 4 play operator) |
//!                   factor index u8 | direction u8 (0 none, 1+axis) | reserved u8, 0 |
//!                   coefficient f64 (µm)
//! then        per axis a with bit a of B set, in axis order, with P_a = the terms of output a
//!             (0..=16, MAX_BOUND_TERMS), all f32 (the device's precision; see crate::bound):
//!                   s f32 (µm) | t95 f32 | mean f32 ×P_a | scale f32 ×P_a |
//!                   R f32 ×(P_a+1)(P_a+2)/2 (upper triangle, row-major, row i = columns i..=P_a)
//! then        72    provenance (crate::provenance; zeros where unknown):
//!             +0  8   fit date i64 (UTC seconds since 1970-01-01; 0: unknown)
//!             +8  8   training data hash u64 (64-bit FNV-1a of the recording's bytes; 0: unknown)
//!             +16 1   stage serial length S (0..=24; 0: unknown, the device checks nothing)
//!             +17 1   unit (0 unknown, 1 µm)
//!             +18 2   reserved, 0
//!             +20 24  stage serial: S printable ASCII bytes (no comma, no space at either end)
//!                     from the controller's `*IDN?`, then zeros
//!             +44 27  per model axis slot 0..3: name length n u8 (0..=8; 0 for a slot ≥ A or
//!                     unknown) | 8 bytes: n printable ASCII bytes (the recording's axis
//!                     name), then zeros
//!             +71 1   reserved, 0
//! ```
//!
//! Version history: 4 added the provenance after the bounds: the stage (its controller's
//! serial), axes and unit the model was fitted on, the fit's date and the hash of its data
//! (a version 1–3 blob decodes with the provenance unknown: the device checks no stage). 3 added the bound mask (payload byte +11, reserved before) and the
//! prediction bounds after the terms: what a device needs to evaluate the fit's prediction
//! interval ([`crate::bound`]). 2 had no aux descriptors (every aux input of kind "other" and slow), no
//! play operators (payload bytes +10 and +11 reserved) and at most 8 temperatures and 8 lags.
//! Version 2 added the aux descriptors, the play operators and factor kind 4, and widened the
//! counts. The decoder still reads version 1, 2 and 3 blobs (a device keeps the models it stored
//! before an update; they carry no provenance, 1 and 2 no bound); the encoder writes version 4
//! only, and an upload must be version 4 (`nanocal_compensator::upload` refuses others by name).
//!
//! The decoder checks everything — lengths, CRC, counts, indices, finiteness, reserved bytes,
//! the order of play operators, the monotonicity of their banks — and returns a typed
//! [`BlobError`]; it never panics, whatever the bytes.

use core::fmt;

use crate::bound::{packed_len, AxisBound, MAX_BOUND_R_LEN, MAX_BOUND_TERMS};
use crate::error::ModelError;
use crate::hysteresis::PlaySpec;
use crate::input::{AuxKind, AuxSpec, Input, Scaling};
use crate::lag::LagSpec;
use crate::limits::{MAX_AUX, MAX_AXES, MAX_INPUTS, MAX_LAGS, MAX_PLAY, MAX_TEMPS, MAX_TERMS};
use crate::model::Model;
use crate::provenance::{
    AxisName, Provenance, ProvenanceUnit, StageSerial, MAX_AXIS_NAME, MAX_SERIAL,
};
use crate::term::{Factor, Term};
use crate::ModelBuilder;

/// First four bytes of every blob.
pub const MAGIC: [u8; 4] = *b"NCAL";
/// Version of the byte layout above; bumped whenever the bytes change.
pub const FORMAT_VERSION: u16 = 4;
/// Version 3 (no provenance), which the decoder still reads.
pub const FORMAT_VERSION_3: u16 = 3;
/// Version 2 (no prediction bounds), which the decoder still reads.
pub const FORMAT_VERSION_2: u16 = 2;
/// Version 1, which the decoder still reads.
pub const FORMAT_VERSION_1: u16 = 1;
/// Bytes before the payload.
pub const HEADER_LEN: usize = 12;
/// Bytes after the payload (the CRC).
pub const TRAILER_LEN: usize = 4;
const PAYLOAD_FIXED_LEN: usize = 12;
const INPUT_LEN: usize = 32;
const AXIS_LEN: usize = 32;
const AUX_LEN: usize = 8;
const LAG_LEN: usize = 16;
const PLAY_LEN: usize = 16;
const TERM_LEN: usize = 16;
/// Bytes of the provenance (version 4).
pub const PROVENANCE_LEN: usize = 72;
const SERIAL_AT: usize = 20;
const AXIS_NAMES_AT: usize = SERIAL_AT + MAX_SERIAL;
const _: () = assert!(AXIS_NAMES_AT + (1 + MAX_AXIS_NAME) * MAX_AXES + 1 == PROVENANCE_LEN);
/// Bytes of one axis' prediction bound with `p` regressors.
const fn bound_len(p: usize) -> usize {
    4 * (2 + 2 * p + packed_len(p))
}
/// Aux flags bit: the input is fast.
const AUX_FAST: u8 = 1;
/// Largest payload a valid blob can have.
pub const MAX_PAYLOAD_LEN: usize = PAYLOAD_FIXED_LEN
    + INPUT_LEN * MAX_INPUTS
    + AXIS_LEN * MAX_AXES
    + AUX_LEN * MAX_AUX
    + LAG_LEN * MAX_LAGS
    + PLAY_LEN * MAX_PLAY
    + TERM_LEN * MAX_TERMS
    + (MAX_AXES - 1) * bound_len(MAX_BOUND_TERMS)
    + PROVENANCE_LEN;
// The largest payload: all MAX_TERMS terms and a full bound on all axes but one (an axis
// with a bound has at most MAX_BOUND_TERMS terms, so the last axis holds the rest, too many
// for a bound; that beats fewer terms and a bound on every axis).
const _: () = assert!(MAX_TERMS - (MAX_AXES - 1) * MAX_BOUND_TERMS > MAX_BOUND_TERMS);
const _: () =
    assert!(TERM_LEN * (MAX_TERMS - MAX_AXES * MAX_BOUND_TERMS) > bound_len(MAX_BOUND_TERMS));
/// Largest valid blob, in bytes.
pub const MAX_BLOB_LEN: usize = HEADER_LEN + MAX_PAYLOAD_LEN + TRAILER_LEN;

/// Why bytes are not a valid blob, or a model could not be encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum BlobError {
    /// Fewer bytes than a header and a CRC.
    TooShort {
        /// Bytes given.
        len: usize,
    },
    /// The first four bytes are not "NCAL".
    BadMagic,
    /// A format version this build does not read (it reads 1 to 4).
    UnsupportedVersion {
        /// Version found.
        found: u16,
    },
    /// The payload length field disagrees with the bytes given.
    LengthMismatch {
        /// Total length the header implies.
        expected: usize,
        /// Bytes given.
        found: usize,
    },
    /// The CRC does not match: the bytes were corrupted.
    CrcMismatch {
        /// CRC stored in the blob.
        stored: u32,
        /// CRC computed over the bytes.
        computed: u32,
    },
    /// The payload length disagrees with the counts it declares.
    PayloadSizeMismatch {
        /// Payload length the counts imply.
        expected: usize,
        /// Payload length in the header.
        found: usize,
    },
    /// A reserved byte is not zero.
    ReservedNotZero {
        /// Offset of the byte in the blob.
        offset: usize,
    },
    /// A term has an unknown factor kind.
    UnknownFactor {
        /// Index of the term.
        term: u16,
        /// Kind byte found.
        kind: u8,
    },
    /// An aux input has an unknown kind.
    UnknownAuxKind {
        /// Index of the aux input.
        aux: u8,
        /// Kind byte found.
        kind: u8,
    },
    /// The provenance holds a value outside its range: a serial or axis name longer than its
    /// field or not printable ASCII, an unknown unit code, bytes after a name's end.
    InvalidProvenance {
        /// Offset of the offending byte in the blob.
        offset: usize,
    },
    /// The bytes describe a model that breaks the model's rules.
    InvalidModel(ModelError),
    /// The output buffer is too small for the encoded model.
    BufferTooSmall {
        /// Bytes needed.
        needed: usize,
    },
}

impl fmt::Display for BlobError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BlobError::TooShort { len } => write!(f, "blob too short: {len} bytes"),
            BlobError::BadMagic => f.write_str("not a nanocal blob (bad magic)"),
            BlobError::UnsupportedVersion { found } => {
                write!(f, "blob format version {found} is not supported (this build reads {FORMAT_VERSION_1} to {FORMAT_VERSION})")
            }
            BlobError::LengthMismatch { expected, found } => {
                write!(
                    f,
                    "blob length mismatch: header says {expected} bytes, got {found}"
                )
            }
            BlobError::CrcMismatch { stored, computed } => {
                write!(
                    f,
                    "blob CRC mismatch: stored {stored:#010x}, computed {computed:#010x}"
                )
            }
            BlobError::PayloadSizeMismatch { expected, found } => {
                write!(
                    f,
                    "blob payload is {found} bytes but its counts need {expected}"
                )
            }
            BlobError::ReservedNotZero { offset } => {
                write!(f, "reserved byte at offset {offset} is not zero")
            }
            BlobError::UnknownFactor { term, kind } => {
                write!(f, "term {term} has unknown factor kind {kind}")
            }
            BlobError::UnknownAuxKind { aux, kind } => {
                write!(f, "aux input {aux} has unknown kind {kind}")
            }
            BlobError::InvalidProvenance { offset } => {
                write!(f, "blob provenance is malformed at offset {offset}")
            }
            BlobError::InvalidModel(e) => write!(f, "blob holds an invalid model: {e}"),
            BlobError::BufferTooSmall { needed } => {
                write!(f, "output buffer too small: need {needed} bytes")
            }
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for BlobError {}

impl From<ModelError> for BlobError {
    fn from(e: ModelError) -> Self {
        BlobError::InvalidModel(e)
    }
}

/// CRC-32/IEEE as zlib computes it (reflected, polynomial 0xEDB88320, init and xorout !0).
/// The project's one CRC-32: the management frames and the settings carry it too
/// (`nanocal_interface::crc32` is this function). Four bits at a time from a 16-entry table
/// (64 B of flash, not a byte table's 1 KiB): two lookups a byte and no branch, where the
/// bitwise loop took ≈ 62 guest instructions a byte (BENCHMARKS.md).
pub fn crc32(bytes: &[u8]) -> u32 {
    crc32_update(0, bytes)
}

/// The CRC-32 a blob carries (its last four bytes, over everything before them): the model's
/// content hash, which the device reports with the model's id (`nanocal_interface::status`).
/// Two blobs that differ in any byte — a coefficient, an envelope, λ_KMZ — differ in it (up
/// to CRC-32's collisions). Read as stored, not checked: `None` for fewer bytes than a header
/// and a CRC; [`decode`] checks it.
pub fn stored_crc(bytes: &[u8]) -> Option<u32> {
    if bytes.len() < HEADER_LEN + TRAILER_LEN {
        return None;
    }
    let t = &bytes[bytes.len() - TRAILER_LEN..];
    Some(u32::from_le_bytes([t[0], t[1], t[2], t[3]]))
}

/// Continues a CRC-32 over more bytes: `crc32_update(crc32(a), b) == crc32(a ++ b)`.
pub fn crc32_update(crc: u32, bytes: &[u8]) -> u32 {
    let mut c = !crc;
    for &b in bytes {
        c ^= b as u32;
        c = CRC32_NIBBLE[(c & 0xF) as usize] ^ (c >> 4);
        c = CRC32_NIBBLE[(c & 0xF) as usize] ^ (c >> 4);
    }
    !c
}

/// The reflected polynomial of CRC-32/IEEE.
const CRC32_POLY: u32 = 0xEDB8_8320;

/// Entry `n`: four bitwise CRC steps from `n` — what the low nibble contributes once shifted
/// out, so that one lookup does the work of four shifts. Built at compile time from the
/// polynomial (no copied constants to get wrong); the standard check value is tested.
const CRC32_NIBBLE: [u32; 16] = {
    let mut table = [0u32; 16];
    let mut n = 0;
    while n < 16 {
        let mut c = n as u32;
        let mut bit = 0;
        while bit < 4 {
            c = (c >> 1) ^ (CRC32_POLY & (c & 1).wrapping_neg());
            bit += 1;
        }
        table[n] = c;
        n += 1;
    }
    table
};

/// The counts a payload declares.
#[derive(Clone, Copy)]
struct Counts {
    axes: usize,
    temps: usize,
    aux: usize,
    lags: usize,
    plays: usize,
    terms: usize,
}

impl Counts {
    fn of(model: &Model) -> Counts {
        Counts {
            axes: model.axes(),
            temps: model.temps(),
            aux: model.aux(),
            lags: model.lags().len(),
            plays: model.play_operators().len(),
            terms: model.terms().len(),
        }
    }

    /// Payload length in format `version` (1 has no aux descriptors, 1–3 no provenance),
    /// bounds not included.
    fn payload_len(&self, version: u16) -> usize {
        let aux_descriptors = if version == FORMAT_VERSION_1 {
            0
        } else {
            AUX_LEN * self.aux
        };
        PAYLOAD_FIXED_LEN
            + INPUT_LEN * (self.axes + self.temps + self.aux)
            + AXIS_LEN * self.axes
            + aux_descriptors
            + LAG_LEN * self.lags
            + PLAY_LEN * self.plays
            + TERM_LEN * self.terms
            + if version >= FORMAT_VERSION {
                PROVENANCE_LEN
            } else {
                0
            }
    }
}

/// Length of the blob `model` encodes to.
pub fn encoded_len(model: &Model) -> usize {
    HEADER_LEN + Counts::of(model).payload_len(FORMAT_VERSION) + bounds_len(model) + TRAILER_LEN
}

/// Bytes of the model's prediction bounds.
fn bounds_len(model: &Model) -> usize {
    (0..model.axes())
        .filter_map(|a| model.bound(a))
        .map(|b| bound_len(b.regressors()))
        .sum()
}

/// The bound mask (payload byte +11).
fn bound_mask(model: &Model) -> u8 {
    (0..model.axes())
        .filter(|&a| model.bound(a).is_some())
        .fold(0, |m, a| m | 1 << a)
}

/// Writes `model` as a blob into `out`; returns the number of bytes written.
pub fn encode(model: &Model, out: &mut [u8]) -> Result<usize, BlobError> {
    let total = encoded_len(model);
    let out = out
        .get_mut(..total)
        .ok_or(BlobError::BufferTooSmall { needed: total })?;
    out.fill(0);
    let mut w = Writer { buf: out, pos: 0 };
    w.bytes(&MAGIC);
    w.u16(FORMAT_VERSION);
    w.u16(0);
    w.u32((total - HEADER_LEN - TRAILER_LEN) as u32);
    w.u32(model.id());
    w.bytes(&[model.axes, model.temps, model.aux, model.lags]);
    w.u16(model.n_terms);
    w.bytes(&[model.plays, bound_mask(model)]);
    for input in model.used_inputs() {
        let s = model.scaling(input);
        let (min, max) = model.envelope(input);
        for v in [s.centre, s.half_range, min, max] {
            w.f64(v);
        }
    }
    for a in 0..model.axes() {
        let (min, max) = model.travel_um(a);
        w.f64(min);
        w.f64(max);
    }
    for a in 0..model.axes() {
        w.f64(model.offset_um(a));
        w.f64(model.kmz_offset_um(a));
    }
    for n in 0..model.aux() {
        let spec = model.aux_spec(n).unwrap_or_default();
        let flags = if spec.fast { AUX_FAST } else { 0 };
        w.bytes(&[spec.kind.code(), flags, 0, 0, 0, 0, 0, 0]);
    }
    for lag in model.lags() {
        w.bytes(&[lag.sensor, 0, 0, 0, 0, 0, 0, 0]);
        w.f64(lag.tau_s);
    }
    for op in model.play_operators() {
        w.bytes(&[op.axis, 0, 0, 0, 0, 0, 0, 0]);
        w.f64(op.threshold_um);
    }
    for t in model.terms() {
        let (kind, index) = match t.factor {
            Factor::None => (0, 0),
            Factor::Temp(n) => (1, n),
            Factor::Aux(n) => (2, n),
            Factor::Lagged(n) => (3, n),
            Factor::Play(n) => (4, n),
        };
        w.bytes(&[
            t.output,
            t.powers[0],
            t.powers[1],
            t.powers[2],
            kind,
            index,
            t.direction,
            0,
        ]);
        w.f64(t.coeff);
    }
    for b in (0..model.axes()).filter_map(|a| model.bound(a)) {
        w.f32(b.s_um());
        w.f32(b.t95());
        for &v in b.mean().iter().chain(b.scale()).chain(b.r_packed()) {
            w.f32(v);
        }
    }
    write_provenance(&mut w, model.provenance(), model.axes());
    let crc = crc32(&w.buf[..w.pos]);
    w.u32(crc);
    Ok(total)
}

/// Reads a blob (format version 4, 3, 2 or 1); every malformation is a typed error, never a panic.
pub fn decode(bytes: &[u8]) -> Result<Model, BlobError> {
    if bytes.len() < HEADER_LEN + TRAILER_LEN {
        return Err(BlobError::TooShort { len: bytes.len() });
    }
    let mut r = Reader { buf: bytes, pos: 0 };
    if r.bytes::<4>()? != MAGIC {
        return Err(BlobError::BadMagic);
    }
    let version = r.u16()?;
    if !(FORMAT_VERSION_1..=FORMAT_VERSION).contains(&version) {
        return Err(BlobError::UnsupportedVersion { found: version });
    }
    r.reserved_u16()?;
    let payload = r.u32()? as usize;
    let expected = HEADER_LEN
        .saturating_add(payload)
        .saturating_add(TRAILER_LEN);
    if expected != bytes.len() {
        return Err(BlobError::LengthMismatch {
            expected,
            found: bytes.len(),
        });
    }
    let body_end = HEADER_LEN + payload;
    let stored = u32::from_le_bytes([
        bytes[body_end],
        bytes[body_end + 1],
        bytes[body_end + 2],
        bytes[body_end + 3],
    ]);
    let computed = crc32(&bytes[..body_end]);
    if stored != computed {
        return Err(BlobError::CrcMismatch { stored, computed });
    }

    let id = r.u32()?;
    let [axes, temps, aux, lags] = r.bytes::<4>()?;
    let n_terms = r.u16()?;
    // Version 1 had a reserved u16 here: zero plays and a zero byte read it the same way.
    let plays = r.bytes::<1>()?[0];
    let mask = if version >= FORMAT_VERSION_3 {
        let mask = r.bytes::<1>()?[0];
        if axes as usize <= MAX_AXES && mask >> axes != 0 {
            return Err(BlobError::ReservedNotZero { offset: r.pos - 1 });
        }
        mask
    } else {
        r.reserved_u8()?;
        0
    };
    let counts = Counts {
        axes: axes as usize,
        temps: temps as usize,
        aux: aux as usize,
        lags: lags as usize,
        plays: plays as usize,
        terms: n_terms as usize,
    };
    let (na, nl, np, nk) = (counts.axes, counts.lags, counts.plays, counts.terms);
    if version == FORMAT_VERSION_1 && np != 0 {
        return Err(BlobError::ReservedNotZero {
            offset: HEADER_LEN + 10,
        });
    }
    if na > MAX_AXES || counts.temps > MAX_TEMPS || counts.aux > MAX_AUX || nl > MAX_LAGS {
        return Err(ModelError::TooManyInputs.into());
    }
    if np > MAX_PLAY {
        return Err(ModelError::TooManyInputs.into());
    }
    if nk > MAX_TERMS {
        return Err(ModelError::TooManyTerms.into());
    }
    let needed = counts.payload_len(version);
    // version 3's and 4's bounds follow the terms: their length is checked once the terms are read
    if needed != payload && !(mask != 0 && needed < payload) {
        return Err(BlobError::PayloadSizeMismatch {
            expected: needed,
            found: payload,
        });
    }

    let mut b = ModelBuilder::new(na, counts.temps, counts.aux)?.id(id);
    let inputs = (0..axes)
        .map(Input::Axis)
        .chain((0..temps).map(Input::Temp))
        .chain((0..aux).map(Input::Aux));
    for input in inputs {
        let scaling = Scaling {
            centre: r.f64()?,
            half_range: r.f64()?,
        };
        let (min, max) = (r.f64()?, r.f64()?);
        b = b.scaling(input, scaling).envelope(input, min, max);
    }
    for a in 0..na {
        let (min, max) = (r.f64()?, r.f64()?);
        b = b.travel_um(a, min, max);
    }
    let mut model = b.into_unchecked();
    for a in 0..na {
        model.offset_um[a] = r.f64()?;
        model.kmz_offset_um[a] = r.f64()?;
    }
    if version != FORMAT_VERSION_1 {
        for n in 0..counts.aux {
            let [code, flags] = r.bytes::<2>()?;
            let kind = AuxKind::from_code(code).ok_or(BlobError::UnknownAuxKind {
                aux: n as u8,
                kind: code,
            })?;
            if flags & !AUX_FAST != 0 {
                return Err(BlobError::ReservedNotZero { offset: r.pos - 1 });
            }
            for _ in 0..6 {
                r.reserved_u8()?;
            }
            model.aux_specs[n] = AuxSpec {
                kind,
                fast: flags & AUX_FAST != 0,
            };
        }
    }
    model.lags = lags;
    for k in 0..nl {
        let sensor = r.bytes::<1>()?[0];
        for _ in 0..7 {
            r.reserved_u8()?;
        }
        model.lag_specs[k] = LagSpec {
            sensor,
            tau_s: r.f64()?,
        };
    }
    model.plays = plays;
    for k in 0..np {
        let axis = r.bytes::<1>()?[0];
        for _ in 0..7 {
            r.reserved_u8()?;
        }
        model.play_specs[k] = PlaySpec {
            axis,
            threshold_um: r.f64()?,
        };
    }
    model.n_terms = n_terms;
    for k in 0..nk {
        let [output, px, py, pz, kind, index, direction] = r.bytes::<7>()?;
        r.reserved_u8()?;
        let factor = match kind {
            0 if index == 0 => Factor::None,
            1 => Factor::Temp(index),
            2 => Factor::Aux(index),
            3 => Factor::Lagged(index),
            4 if version != FORMAT_VERSION_1 => Factor::Play(index),
            _ => {
                return Err(BlobError::UnknownFactor {
                    term: k as u16,
                    kind,
                })
            }
        };
        model.terms[k] = Term {
            output,
            powers: [px, py, pz],
            factor,
            direction,
            coeff: r.f64()?,
        };
    }
    let mut bounds_needed = 0usize;
    for a in (0..na).filter(|a| mask & 1 << a != 0) {
        let p = model.axis_terms(a);
        if p > MAX_BOUND_TERMS {
            return Err(ModelError::InvalidBound.into());
        }
        bounds_needed += bound_len(p);
    }
    if needed + bounds_needed != payload {
        return Err(BlobError::PayloadSizeMismatch {
            expected: needed + bounds_needed,
            found: payload,
        });
    }
    model.validate()?;
    for a in (0..na).filter(|a| mask & 1 << a != 0) {
        let p = model.axis_terms(a);
        let (s_um, t95) = (r.f32()?, r.f32()?);
        let mut mean = [0.0f32; MAX_BOUND_TERMS];
        let mut scale = [0.0f32; MAX_BOUND_TERMS];
        let mut rp = [0.0f32; MAX_BOUND_R_LEN];
        for v in mean[..p].iter_mut().chain(&mut scale[..p]) {
            *v = r.f32()?;
        }
        for v in rp[..packed_len(p)].iter_mut() {
            *v = r.f32()?;
        }
        let bound = AxisBound::new(s_um, t95, &mean[..p], &scale[..p], &rp[..packed_len(p)])?;
        model.set_bound(a, Some(bound))?;
    }
    if version >= FORMAT_VERSION {
        model.provenance = read_provenance(&mut r, na)?;
    }
    Ok(model)
}

/// Writes the provenance section (version 4).
fn write_provenance(w: &mut Writer<'_>, p: &Provenance, axes_n: usize) {
    let start = w.pos;
    w.bytes(&p.fit_date_s.to_le_bytes());
    w.bytes(&p.data_fnv64.to_le_bytes());
    let serial = p.stage_serial.as_ref().map_or(&[][..], |s| s.as_bytes());
    w.bytes(&[serial.len() as u8, p.unit.code()]);
    w.pos = start + SERIAL_AT;
    w.bytes(serial);
    for (a, name) in p.axes.iter().enumerate().take(axes_n) {
        w.pos = start + AXIS_NAMES_AT + a * (1 + MAX_AXIS_NAME);
        let name = name.as_ref().map_or(&[][..], |n| n.as_bytes());
        w.bytes(&[name.len() as u8]);
        w.bytes(name);
    }
    // the buffer was zeroed: reserved bytes and padding stay 0
    w.pos = start + PROVENANCE_LEN;
}

/// Reads the provenance section (version 4): every length in range, every text printable,
/// every byte after a text's end zero.
fn read_provenance(r: &mut Reader<'_>, axes_n: usize) -> Result<Provenance, BlobError> {
    let start = r.pos;
    let fit_date_s = i64::from_le_bytes(r.bytes()?);
    let data_fnv64 = u64::from_le_bytes(r.bytes()?);
    let [s_len, unit] = r.bytes::<2>()?;
    let bad = |at: usize| BlobError::InvalidProvenance { offset: start + at };
    let unit = ProvenanceUnit::from_code(unit).ok_or(bad(17))?;
    r.reserved_u16()?;
    let serial_field = r.bytes::<MAX_SERIAL>()?;
    let s_len = usize::from(s_len);
    if s_len > MAX_SERIAL {
        return Err(bad(16));
    }
    let stage_serial = match s_len {
        0 => None,
        n => Some(StageSerial::new(&serial_field[..n]).ok_or(bad(SERIAL_AT))?),
    };
    if let Some(k) = serial_field[s_len..].iter().position(|&b| b != 0) {
        return Err(bad(SERIAL_AT + s_len + k));
    }
    let mut axes = [None; MAX_AXES];
    for (a, slot) in axes.iter_mut().enumerate() {
        let at = AXIS_NAMES_AT + a * (1 + MAX_AXIS_NAME);
        let [n] = r.bytes::<1>()?;
        let field = r.bytes::<MAX_AXIS_NAME>()?;
        let n = usize::from(n);
        if n > MAX_AXIS_NAME || (n > 0 && a >= axes_n) {
            return Err(bad(at));
        }
        if n > 0 {
            *slot = Some(AxisName::new(&field[..n]).ok_or(bad(at + 1))?);
        }
        if let Some(k) = field[n..].iter().position(|&b| b != 0) {
            return Err(bad(at + 1 + n + k));
        }
    }
    r.reserved_u8()?;
    Ok(Provenance {
        stage_serial,
        axes,
        unit,
        fit_date_s,
        data_fnv64,
    })
}

struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl Writer<'_> {
    fn bytes(&mut self, b: &[u8]) {
        self.buf[self.pos..self.pos + b.len()].copy_from_slice(b);
        self.pos += b.len();
    }
    fn u16(&mut self, v: u16) {
        self.bytes(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.bytes(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.bytes(&v.to_le_bytes());
    }
    fn f32(&mut self, v: f32) {
        self.bytes(&v.to_le_bytes());
    }
}

struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl Reader<'_> {
    fn bytes<const N: usize>(&mut self) -> Result<[u8; N], BlobError> {
        let end = self.pos.checked_add(N).filter(|&e| e <= self.buf.len());
        let slice = end.and_then(|e| self.buf.get(self.pos..e));
        let out: [u8; N] = slice
            .and_then(|s| s.try_into().ok())
            .ok_or(BlobError::TooShort {
                len: self.buf.len(),
            })?;
        self.pos += N;
        Ok(out)
    }
    fn u16(&mut self) -> Result<u16, BlobError> {
        Ok(u16::from_le_bytes(self.bytes()?))
    }
    fn u32(&mut self) -> Result<u32, BlobError> {
        Ok(u32::from_le_bytes(self.bytes()?))
    }
    fn f64(&mut self) -> Result<f64, BlobError> {
        Ok(f64::from_le_bytes(self.bytes()?))
    }
    fn f32(&mut self) -> Result<f32, BlobError> {
        Ok(f32::from_le_bytes(self.bytes()?))
    }
    fn reserved_u8(&mut self) -> Result<(), BlobError> {
        let offset = self.pos;
        match self.bytes::<1>()? {
            [0] => Ok(()),
            _ => Err(BlobError::ReservedNotZero { offset }),
        }
    }
    fn reserved_u16(&mut self) -> Result<(), BlobError> {
        self.reserved_u8()?;
        self.reserved_u8()
    }
}
