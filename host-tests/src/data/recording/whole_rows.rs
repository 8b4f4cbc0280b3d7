//! Whole rows of the common form, parsed in two passes over a few kilobytes of input at a time:
//! first every delimiter's position into a list, then the fields between them.
//!
//! The common form is what instruments and nanocal's own tools write: every row `ncol` fields,
//! each an optional `-`, 1–8 digits, a point and 1–8 decimals (15 digits at most), separated
//! by `,`, the row ended by `\n` or `\r\n`. Anything else — a blank line, spaces, an exponent,
//! a long mantissa, a missing or extra field, the last bytes of the input — stops this path at
//! that row; the caller parses the row the general way ([`super::parse_row`]), which reports
//! errors, and comes back.
//!
//! Why two passes: the general path finds each field's end while it reads the field — through
//! a 64-byte window of delimiters that it checks and refills field by field, the delimiter
//! byte loaded again to tell `,` from `\n` — and the next field's start waits for that end.
//! With every position listed first (as simdjson's stage 1 lists its structural characters),
//! the fields of a row depend on the list, not on each other: the CPU converts several at once,
//! and a row's bookkeeping is a few compares. On the 200,000 × 40 stepwise design, one thread,
//! input in cache: 0.94 ns a byte against the general path's 1.20 (best of 10, the two in turn
//! in one process); `nanocal stepwise` on the file: BENCHMARKS.md ("stepwise from the file").

/// Bytes indexed at a time: small enough that the list stays in the level-1 cache and that a
/// row the fast path cannot take costs little indexing thrown away; large enough that the
/// partial row at a segment's end, indexed twice, is a small share.
pub(super) const SEGMENT: usize = 8 << 10;

/// How far past a field's start the input must go: its 16-byte load, and a 64-byte block of
/// indexing at a segment's end.
pub(super) const REACH: usize = 80;

/// The reusable list of delimiter positions.
pub(super) struct WholeRows {
    /// Positions of `,` and `\n` in the current segment, relative to its start; room for one
    /// more block's worth past the end (the flattening writes ahead).
    delimiters: Vec<u32>,
}

impl WholeRows {
    pub(super) fn new() -> WholeRows {
        WholeRows {
            delimiters: vec![0; SEGMENT + 64],
        }
    }

    /// Parses rows of the common form from `pos` (the start of a line) into place `row` of
    /// `columns` and the places after it, at most `max_rows` rows; stops before the first row
    /// it cannot take. Returns the rows parsed and where the line after them starts.
    pub(super) fn take(
        &mut self,
        bytes: &[u8],
        pos: usize,
        columns: &mut [&mut [f64]],
        row: usize,
        max_rows: usize,
    ) -> (usize, usize) {
        let room = columns.iter().map(|c| c.len()).min().unwrap_or(0);
        let max_rows = max_rows.min(room.saturating_sub(row));
        if columns.is_empty() || max_rows == 0 {
            return (0, pos);
        }
        #[cfg(target_arch = "x86_64")]
        if cpu_has_features() {
            // SAFETY: the CPU has the features; every column has room for `max_rows` rows from
            // `row` (checked above)
            return unsafe { self.take_ssse3(bytes, pos, columns, row, max_rows) };
        }
        (0, pos)
    }

    /// Parses the lines of `bytes[from..end]` (whole lines: `end` just after a newline) as rows
    /// of the common form into the places `top - lines..top` of every column, the last line at
    /// `top - 1`: for a parse from the last row down that places rows before it knows how many
    /// there are, without counting the lines first. Returns the number of lines if it took
    /// them all; `None` if not (a blank line or a row not of the common form among them, more
    /// than a segment of bytes, fewer than [`REACH`] bytes after `end`, more lines than `top`):
    /// some of those places may then hold values of no row, and the caller parses the lines
    /// again the general way.
    pub(super) fn take_below(
        &mut self,
        bytes: &[u8],
        from: usize,
        end: usize,
        columns: &mut [&mut [f64]],
        top: usize,
    ) -> Option<usize> {
        let room = columns.iter().map(|c| c.len()).min().unwrap_or(0);
        if columns.is_empty()
            || top > room
            || from >= end
            || end - from > SEGMENT
            || end + REACH > bytes.len()
        {
            return None;
        }
        #[cfg(target_arch = "x86_64")]
        if cpu_has_features() {
            // SAFETY: the CPU has the features; the bounds are checked above
            return unsafe { self.take_below_ssse3(bytes, from, end, columns, top) };
        }
        None
    }

    /// [`Self::take_below`] where the CPU has SSSE3, POPCNT and BMI1.
    ///
    /// # Safety
    /// The CPU has SSSE3, POPCNT and BMI1; `from < end`, `end - from ≤ SEGMENT`,
    /// `end + REACH ≤ bytes.len()`, every column at least `top` long.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "ssse3,popcnt,bmi1")]
    unsafe fn take_below_ssse3(
        &mut self,
        bytes: &[u8],
        from: usize,
        end: usize,
        columns: &mut [&mut [f64]],
        top: usize,
    ) -> Option<usize> {
        let ncol = columns.len();
        let b = bytes.as_ptr();
        // SAFETY: [from, end) plus 63 bytes lie in `bytes` (`REACH`); at most a segment
        let found = unsafe { self.index(b, from, end) };
        if found == 0 || !found.is_multiple_of(ncol) || found / ncol > top {
            return None;
        }
        let lines = found / ncol;
        let first = top - lines;
        let list = self.delimiters.as_ptr();
        let mut start = from;
        for line in 0..lines {
            // SAFETY: the row's ncol entries of the list were written by `index` (line · ncol
            // + ncol ≤ found), its delimiters lie in [from, end), at least REACH bytes before
            // the end of `bytes`; first + line < top ≤ every column's length
            start = unsafe {
                parse_row_whole(b, list.add(line * ncol), from, start, columns, first + line)
            }?;
        }
        // every delimiter of [from, end) ended a field, the last one a row: `start` is `end`
        Some(lines)
    }

    /// [`Self::take`] where the CPU has SSSE3, POPCNT and BMI1.
    ///
    /// # Safety
    /// The CPU has SSSE3, POPCNT and BMI1; every column has room for `max_rows` rows from `row`.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "ssse3,popcnt,bmi1")]
    unsafe fn take_ssse3(
        &mut self,
        bytes: &[u8],
        pos: usize,
        columns: &mut [&mut [f64]],
        row: usize,
        max_rows: usize,
    ) -> (usize, usize) {
        let n = bytes.len();
        if n < REACH {
            return (0, pos);
        }
        // fields start and blocks of indexing end before this
        let limit = n - REACH;
        let ncol = columns.len();
        let b = bytes.as_ptr();
        let mut rows = 0usize;
        let mut row_start = pos;
        'segments: while rows < max_rows && row_start < limit {
            let seg = row_start;
            let seg_end = (seg + SEGMENT).min(limit);
            // SAFETY: [seg, seg_end) plus 63 bytes lie in `bytes` (`limit`)
            let found = unsafe { self.index(b, seg, seg_end) };
            let list = self.delimiters.as_ptr();
            let mut k = 0usize;
            let mut rows_here = 0usize;
            loop {
                if rows == max_rows {
                    break 'segments;
                }
                if k + ncol > found {
                    if rows_here == 0 {
                        // a row longer than a segment, or the end: the general path
                        break 'segments;
                    }
                    continue 'segments;
                }
                // SAFETY: entries k..k + ncol ≤ found of the list were written by `index`;
                // the delimiters lie before seg_end ≤ limit (REACH bytes before the end);
                // row + rows < row + max_rows ≤ every column's length
                let next =
                    unsafe { parse_row_whole(b, list.add(k), seg, row_start, columns, row + rows) };
                let Some(next) = next else {
                    break 'segments;
                };
                k += ncol;
                rows += 1;
                rows_here += 1;
                row_start = next;
            }
        }
        (rows, row_start)
    }

    /// Lists the positions of `,` and `\n` in `[seg, seg_end)` (relative to `seg`), 64 bytes at
    /// a time; returns how many. The flattening writes eight positions whatever the count, then
    /// more only for a block with more than eight (simdjson's `flatten_bits`): a loop that
    /// stops at a block's last delimiter (six or seven here) would end on a branch that varies
    /// block by block.
    ///
    /// # Safety
    /// `seg_end - seg ≤ SEGMENT`; the bytes from `b + seg` to `b + seg_end + 63` are readable.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "ssse3,popcnt,bmi1")]
    unsafe fn index(&mut self, b: *const u8, seg: usize, seg_end: usize) -> usize {
        use std::arch::x86_64::*;
        let out = self.delimiters.as_mut_ptr();
        let mut found = 0usize;
        let mut at = seg;
        while at < seg_end {
            // SAFETY: 64 bytes from `at` are readable (the caller's)
            let mut mask = unsafe {
                let mut m = 0u64;
                for q in 0..4 {
                    let v = _mm_loadu_si128(b.add(at + 16 * q) as *const __m128i);
                    let d = _mm_or_si128(
                        _mm_cmpeq_epi8(v, _mm_set1_epi8(b',' as i8)),
                        _mm_cmpeq_epi8(v, _mm_set1_epi8(b'\n' as i8)),
                    );
                    m |= (_mm_movemask_epi8(d) as u16 as u64) << (16 * q);
                }
                m
            };
            if seg_end - at < 64 {
                mask &= (1u64 << (seg_end - at)) - 1;
            }
            let base = (at - seg) as u32;
            let count = mask.count_ones() as usize;
            // SAFETY: `found` ≤ the bytes indexed so far ≤ SEGMENT - 64 before this block;
            // the list has room for SEGMENT + 64 entries, so 64 more fit
            unsafe {
                for q in 0..8 {
                    *out.add(found + q) = base + mask.trailing_zeros();
                    mask &= mask.wrapping_sub(1);
                }
                if count > 8 {
                    let mut q = 8;
                    while mask != 0 {
                        *out.add(found + q) = base + mask.trailing_zeros();
                        mask &= mask - 1;
                        q += 1;
                    }
                }
            }
            found += count;
            at += 64;
        }
        found
    }
}

/// Whether the CPU has what the fast path is compiled for: SSSE3, POPCNT and BMI1 (every
/// x86-64 of the last ten years; the flags are read once and cached by the standard library).
#[cfg(target_arch = "x86_64")]
#[inline]
fn cpu_has_features() -> bool {
    std::arch::is_x86_feature_detected!("ssse3")
        && std::arch::is_x86_feature_detected!("popcnt")
        && std::arch::is_x86_feature_detected!("bmi1")
}

/// Parses the row that starts at `start`, its fields ended by the delimiters at `base +
/// list[0..ncol]`, into place `place` of every column; where the next line starts, or `None`
/// if a field is not of the common form or a delimiter is not the one its place asks for (then
/// some of the row's places hold values of no row). The last field out of the loop: the loop's
/// fields need no test of their place.
///
/// # Safety
/// The CPU has SSSE3, POPCNT and BMI1; `list` has `columns.len()` entries, ascending, each
/// `base +` it after `start` and at least [`REACH`] bytes before the end of the input at `b`;
/// `place` is within every column.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "ssse3,popcnt,bmi1")]
#[inline]
unsafe fn parse_row_whole(
    b: *const u8,
    list: *const u32,
    base: usize,
    mut start: usize,
    columns: &mut [&mut [f64]],
    place: usize,
) -> Option<usize> {
    let Some((last, before)) = columns.split_last_mut() else {
        return Some(start);
    };
    // SAFETY: the caller's: the entries, the bytes around each field and the places exist
    unsafe {
        for (c, column) in before.iter_mut().enumerate() {
            let end = base + *list.add(c) as usize;
            *column.as_mut_ptr().add(place) = field(b, start, end, false)?;
            start = end + 1;
        }
        let end = base + *list.add(before.len()) as usize;
        *last.as_mut_ptr().add(place) = field(b, start, end, true)?;
        Some(end + 1)
    }
}

/// The field from `start` to its delimiter at `end` if it is of the common form and the
/// delimiter is the one its place asks for (`\n` for the `last` field, `,` before it): the
/// value, bit for bit what the general path reads (the mantissa below 10¹⁵ < 2⁵³, one exact
/// division: Clinger's fast path).
///
/// # Safety
/// The CPU has SSSE3 and BMI1; the bytes from `b + start` to `b + start + 17` and at
/// `b + end` are readable; `start ≤ end`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "ssse3,popcnt,bmi1")]
#[inline]
unsafe fn field(b: *const u8, start: usize, end: usize, last: bool) -> Option<f64> {
    use std::arch::x86_64::*;
    // SAFETY: the caller's: these bytes are readable
    unsafe {
        let delimiter = *b.add(end);
        let mut end = end;
        if last && end > start && *b.add(end - 1) == b'\r' {
            end -= 1;
        }
        if delimiter != if last { b'\n' } else { b',' } {
            return None;
        }
        let neg = *b.add(start) == b'-';
        let p = start + neg as usize;
        let v = _mm_loadu_si128(b.add(p) as *const __m128i);
        let point = (_mm_movemask_epi8(_mm_cmpeq_epi8(v, _mm_set1_epi8(b'.' as i8))) as u32)
            .trailing_zeros() as usize;
        // digits before and after the point: 1–8 each (wrapping: a point before `p` or none
        // at all fails too), 15 in all
        let nd = point;
        let nf = end.wrapping_sub(p + point + 1);
        // both within 1..=8 (the table refuses more than 15 in all)
        if (nd.wrapping_sub(1) | nf.wrapping_sub(1)) >= 8 {
            return None;
        }
        let d = _mm_sub_epi8(v, _mm_set1_epi8(b'0' as i8));
        let digit = _mm_movemask_epi8(_mm_cmpeq_epi8(_mm_min_epu8(d, _mm_set1_epi8(9)), d)) as u32;
        let shape = 8 * (nd - 1) + nf - 1;
        let want = DIGITS_WANTED[shape];
        if digit & want != want {
            return None;
        }
        let mant = super::digits_value_ssse3(d, shape);
        let value = mant as i64 as f64 / super::POW10[nf];
        Some(if neg { -value } else { value })
    }
}

/// Which of the 16 bytes must be digits for a field of `nd` integer digits and `nf` decimals,
/// by `8 · (nd − 1) + nf − 1` as [`super::DIGIT_SHUFFLES`]: bits `0..nd` and
/// `nd + 1..nd + 1 + nf`; for more than 15 digits in all a bit no byte sets (bit 16), so the
/// shape is refused by the same test.
#[cfg(target_arch = "x86_64")]
static DIGITS_WANTED: [u32; 64] = {
    let mut t = [0u32; 64];
    let mut nd = 1;
    while nd <= 8 {
        let mut nf = 1;
        while nf <= 8 {
            t[8 * (nd - 1) + nf - 1] = if nd + nf > 15 {
                1 << 16
            } else {
                ((1u32 << nd) - 1) | (((1u32 << nf) - 1) << (nd + 1))
            };
            nf += 1;
        }
        nd += 1;
    }
    t
};

#[cfg(all(test, target_arch = "x86_64"))]
mod tests {
    use super::*;

    /// A xorshift generator: the same fields every run.
    struct Fields(u64);

    impl Fields {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }

        /// A field of the common form: every shape (1–8 digits each side of the point, 15 at
        /// most), a sign on a third of them, zeros leading and trailing.
        fn common(&mut self) -> String {
            let r = self.next();
            let nd = 1 + (r % 8) as usize;
            let nf = (1 + ((r >> 3) % 8) as usize).min(15 - nd);
            let digit = |k: usize| char::from(b'0' + ((r >> (6 + 3 * k)) % 10) as u8);
            let int: String = (0..nd).map(digit).collect();
            let frac: String = (nd..nd + nf).map(digit).collect();
            let sign = if (r >> 62) == 0 { "-" } else { "" };
            format!("{sign}{int}.{frac}")
        }
    }

    /// `rows` rows of `ncol` common fields (every seventh ended by CR LF), their values as the
    /// standard library reads them, and where each row starts (and where they end); then rows
    /// of padding, as long as the fast path's reach past a field.
    fn common_rows(ncol: usize, rows: usize, seed: u64) -> (Vec<u8>, Vec<Vec<f64>>, Vec<usize>) {
        let mut gen = Fields(seed);
        let mut text = String::new();
        let mut want = vec![Vec::new(); ncol];
        let mut starts = Vec::new();
        for row in 0..rows {
            starts.push(text.len());
            let fields: Vec<String> = (0..ncol).map(|_| gen.common()).collect();
            for (c, f) in fields.iter().enumerate() {
                want[c].push(f.parse::<f64>().expect("a number"));
            }
            text.push_str(&fields.join(","));
            text.push_str(if row % 7 == 3 { "\r\n" } else { "\n" });
        }
        starts.push(text.len());
        let padded = text.len() + 2 * REACH;
        while text.len() < padded {
            text.push_str(&vec!["1.5"; ncol].join(","));
            text.push('\n');
        }
        (text.into_bytes(), want, starts)
    }

    fn columns_of(ncol: usize, room: usize) -> Vec<Vec<f64>> {
        vec![vec![f64::NAN; room]; ncol]
    }

    #[test]
    fn rows_of_the_common_form_read_bit_identical_to_std() {
        for ncol in [1, 3, 41] {
            let rows = 3000 / ncol + 200;
            let (bytes, want, starts) =
                common_rows(ncol, rows, 0x9e37_79b9_7f4a_7c15 + ncol as u64);
            let mut cols = columns_of(ncol, rows + 10);
            let mut views: Vec<&mut [f64]> = cols.iter_mut().map(|c| c.as_mut_slice()).collect();
            let (taken, next) = WholeRows::new().take(&bytes, 0, &mut views, 5, rows);
            assert_eq!((taken, next), (rows, starts[rows]), "{ncol} columns");
            for (c, w) in want.iter().enumerate() {
                for (i, w) in w.iter().enumerate() {
                    let got = cols[c][5 + i];
                    assert_eq!(got.to_bits(), w.to_bits(), "row {i} column {c}: {w}");
                }
            }
        }
    }

    #[test]
    fn lines_taken_below_a_place_fill_the_places_under_it() {
        let ncol = 4;
        let (bytes, want, starts) = common_rows(ncol, 400, 7);
        // lines 100..150, placed just below 300: line 149 at 299
        let (from, end) = (starts[100], starts[150]);
        let mut cols = columns_of(ncol, 300);
        let mut views: Vec<&mut [f64]> = cols.iter_mut().map(|c| c.as_mut_slice()).collect();
        let lines = WholeRows::new().take_below(&bytes, from, end, &mut views, 300);
        assert_eq!(lines, Some(50));
        for c in 0..ncol {
            for k in 0..50 {
                assert_eq!(cols[c][250 + k].to_bits(), want[c][100 + k].to_bits());
            }
            assert!(cols[c][249].is_nan() && cols[c][..250].iter().all(|v| v.is_nan()));
        }
        // more lines than places below the top: none taken
        let mut views: Vec<&mut [f64]> = cols.iter_mut().map(|c| c.as_mut_slice()).collect();
        assert_eq!(
            WholeRows::new().take_below(&bytes, from, end, &mut views, 49),
            None
        );
        // the end of the input: the loads would reach past it
        let tail = &bytes[..end];
        let mut views: Vec<&mut [f64]> = cols.iter_mut().map(|c| c.as_mut_slice()).collect();
        assert_eq!(
            WholeRows::new().take_below(tail, from, end, &mut views, 300),
            None
        );
    }

    /// Every kind of row the fast path must leave to the general one: it stops at that row
    /// (having taken the rows before it), and refuses a batch that holds it.
    #[test]
    fn the_fast_path_stops_at_the_first_row_it_cannot_take() {
        let ncol = 3;
        let interruptions = [
            "",
            " 1.5,2.5,3.5",
            "1.5, 2.5,3.5",
            "1.5,2.5,3.5 ",
            "\t1.5,2.5,3.5",
            "1e5,2.5,3.5",
            "1.5,2.5e-3,3.5",
            "123456789.5,2.5,3.5",
            "1.123456789,2.5,3.5",
            "12345678.12345678,2.5,3.5",
            "1,2.5,3.5",
            ".5,2.5,3.5",
            "5.,2.5,3.5",
            "+1.5,2.5,3.5",
            "-,2.5,3.5",
            "--1.5,2.5,3.5",
            "1.5.5,2.5,3.5",
            "1.5,2.5",
            "1.5,2.5,3.5,4.5",
            "1.5,,3.5",
            "1.5,x.5,3.5",
            "1.5,2.5,3.5\r\r",
            "NaN,2.5,3.5",
        ];
        for bad in interruptions {
            let (good, _, starts) = common_rows(ncol, 100, 11);
            let mut text = good[..starts[37]].to_vec();
            text.extend_from_slice(bad.as_bytes());
            text.push(b'\n');
            text.extend_from_slice(&good[starts[37]..]);
            let mut cols = columns_of(ncol, 200);
            let mut views: Vec<&mut [f64]> = cols.iter_mut().map(|c| c.as_mut_slice()).collect();
            let (taken, next) = WholeRows::new().take(&text, 0, &mut views, 0, 200);
            assert_eq!((taken, next), (37, starts[37]), "{bad:?}");
            let mut views: Vec<&mut [f64]> = cols.iter_mut().map(|c| c.as_mut_slice()).collect();
            let below = WholeRows::new().take_below(
                &text,
                starts[30],
                starts[40] + bad.len() + 1,
                &mut views,
                200,
            );
            assert_eq!(below, None, "{bad:?}");
        }
    }
}
