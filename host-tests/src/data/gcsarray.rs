//! PI data-recorder files: GCSArray text, as PI's software and PIPython write them, and the
//! text of a `DRR?` reply (PIPython's `qDRR`).
//!
//! The format, as PIPython 2.11 writes and reads it (`pipython/pitools/common/gcsbasepitools.py`,
//! `GCSBaseTools.savegcsarray` / `readgcsarray`; `pipython/pidevice/common/gcscommands_helpers.py`,
//! `getgcsheader`; `pipython/pidevice/gcsmessages.py`, `GCSMessages.read` for `DRR?`):
//!
//! ```text
//! [GCS_ARRAY …]              optional; anything before it, or before the first `#` line, is skipped
//! # VERSION = 1              header: `# KEY = value` lines (other `#` lines are comments)
//! # TYPE = 1
//! # SEPARATOR = 32           the column separator as a character code (32: space, 9: tab, 44: comma)
//! # DIM = 2                  number of columns (recorded tables)
//! # NDATA = 1000             rows
//! # SAMPLE_TIME = 0.0001     s between rows (in a DRR? reply; optional)
//! # NAME0 = Target Position of axis 1    per table, what it recorded (DRR?; optional)
//! #
//! # END_HEADER
//! 0.000000 0.001000          one row per sample, values joined by the separator, 6 decimals
//! ```
//!
//! PIPython's own `DRR?` reader splits data lines on whitespace whatever the separator; so does
//! this one when `SEPARATOR` is 32 or absent. Stricter than PIPython where PIPython would fail
//! later or silently: every header line must be `# KEY = value` or a comment, `DIM` and `NDATA`
//! must agree with the data, and every row must have `DIM` numbers — a bad line is an error
//! naming its line number (1-based).

use std::path::Path;

/// Errors reading a GCSArray file.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum GcsArrayError {
    /// The file has no header (`#` lines) at all.
    #[error("no GCSArray header: expected `# KEY = value` lines ending with `# END_HEADER`")]
    NoHeader,
    /// The header never ends.
    #[error("line {0}: the file ends inside the header: expected `# END_HEADER`")]
    NoEndHeader(usize),
    /// A header value is not what its key needs.
    #[error("line {line}: header `{key}`: {problem}")]
    BadHeader {
        /// 1-based line.
        line: usize,
        /// The key.
        key: String,
        /// What is wrong.
        problem: String,
    },
    /// A data row is malformed.
    #[error("line {line}: {problem}")]
    BadRow {
        /// 1-based line.
        line: usize,
        /// What is wrong.
        problem: String,
    },
    /// The header's counts disagree with the data.
    #[error("header says {key} = {declared}, the data have {found}")]
    CountMismatch {
        /// `DIM` or `NDATA`.
        key: &'static str,
        /// Declared in the header.
        declared: usize,
        /// Found in the data.
        found: usize,
    },
    /// The file could not be read.
    #[error("{0}")]
    Io(String),
}

/// A data-recorder file: header items in file order and one column per recorded table.
#[derive(Debug, Clone, PartialEq)]
pub struct GcsArray {
    /// `(KEY, value)` as written, in file order.
    pub header: Vec<(String, String)>,
    /// Per table (column), its values.
    pub tables: Vec<Vec<f64>>,
}

impl GcsArray {
    /// A header value by key.
    pub fn get(&self, key: &str) -> Option<&str> {
        self.header
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    /// The name of table `i` (0-based): its `NAME<i>` header item, if any.
    pub fn name(&self, i: usize) -> Option<&str> {
        self.get(&format!("NAME{i}"))
    }

    /// `SAMPLE_TIME`, s, if the header has it.
    pub fn sample_time_s(&self) -> Option<f64> {
        self.get("SAMPLE_TIME").and_then(|v| v.parse().ok())
    }

    /// Rows.
    pub fn rows(&self) -> usize {
        self.tables.first().map_or(0, |t| t.len())
    }

    /// Reads a file.
    pub fn read_path(path: &Path) -> Result<Self, GcsArrayError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| GcsArrayError::Io(format!("{}: {e}", path.display())))?;
        Self::parse(&text)
    }

    /// Parses GCSArray text (see the module doc).
    pub fn parse(text: &str) -> Result<Self, GcsArrayError> {
        let mut header: Vec<(String, String)> = Vec::new();
        let mut header_lines: Vec<usize> = Vec::new();
        let mut started = false;
        let mut ended = false;
        let mut rows: Vec<(usize, &str)> = Vec::new();
        let mut last_line = 0;
        for (k, raw) in text.lines().enumerate() {
            let line = k + 1;
            last_line = line;
            let l = raw.trim_end_matches('\r');
            if !started {
                if l.starts_with("[GCS_ARRAY") {
                    started = true;
                    continue;
                }
                if !l.starts_with('#') {
                    continue;
                }
                started = true;
            }
            if let Some(rest) = l.strip_prefix('#') {
                if ended {
                    return Err(GcsArrayError::BadRow {
                        line,
                        problem: format!("header line `{l}` after `# END_HEADER`"),
                    });
                }
                let item = rest.trim();
                if item.eq_ignore_ascii_case("END_HEADER") {
                    ended = true;
                    continue;
                }
                if let Some((key, value)) = item.split_once('=') {
                    let key = key.trim();
                    if key.is_empty() || key.contains(char::is_whitespace) {
                        return Err(GcsArrayError::BadHeader {
                            line,
                            key: key.to_string(),
                            problem: format!("expected `# KEY = value`, found `{l}`"),
                        });
                    }
                    header.push((key.to_string(), value.trim().to_string()));
                    header_lines.push(line);
                }
                // other `#` lines (`#`, `# REM …`) are comments
                continue;
            }
            if !ended {
                if l.trim().is_empty() {
                    continue;
                }
                return Err(GcsArrayError::BadRow {
                    line,
                    problem: format!(
                        "expected a `# KEY = value` header line or `# END_HEADER`, found `{l}`"
                    ),
                });
            }
            if l.trim().is_empty() {
                continue;
            }
            rows.push((line, l));
        }
        if !started {
            return Err(GcsArrayError::NoHeader);
        }
        if !ended {
            return Err(GcsArrayError::NoEndHeader(last_line));
        }
        let line_of = |key: &str| {
            header
                .iter()
                .zip(&header_lines)
                .find(|((k, _), _)| k == key)
                .map(|(_, l)| *l)
        };
        let count = |key: &'static str| -> Result<Option<usize>, GcsArrayError> {
            match header.iter().find(|(k, _)| k == key) {
                None => Ok(None),
                Some((_, v)) => {
                    v.parse::<usize>()
                        .map(Some)
                        .map_err(|_| GcsArrayError::BadHeader {
                            line: line_of(key).unwrap_or(0),
                            key: key.to_string(),
                            problem: format!("expected a whole number, found `{v}`"),
                        })
                }
            }
        };
        let dim = count("DIM")?;
        let ndata = count("NDATA")?;
        let sep: Option<char> = match header.iter().find(|(k, _)| k == "SEPARATOR") {
            None => None,
            Some((_, v)) => {
                let code: u32 = v.parse().map_err(|_| GcsArrayError::BadHeader {
                    line: line_of("SEPARATOR").unwrap_or(0),
                    key: "SEPARATOR".into(),
                    problem: format!(
                        "expected a character code (32 space, 9 tab, 44 comma), found `{v}`"
                    ),
                })?;
                let c = char::from_u32(code)
                    .filter(|c| !c.is_alphanumeric() && *c != '.' && *c != '-' && *c != '+')
                    .ok_or_else(|| GcsArrayError::BadHeader {
                        line: line_of("SEPARATOR").unwrap_or(0),
                        key: "SEPARATOR".into(),
                        problem: format!("character code {code} cannot separate numbers"),
                    })?;
                Some(c)
            }
        };
        let mut tables: Vec<Vec<f64>> = Vec::new();
        for (line, l) in &rows {
            let fields: Vec<&str> = match sep {
                None | Some(' ') => l.split_whitespace().collect(),
                Some(c) => l.trim().split(c).map(str::trim).collect(),
            };
            let want = dim.unwrap_or(if tables.is_empty() {
                fields.len()
            } else {
                tables.len()
            });
            if fields.len() != want {
                return Err(GcsArrayError::BadRow {
                    line: *line,
                    problem: format!(
                        "expected {want} values (DIM), found {}: `{l}`",
                        fields.len()
                    ),
                });
            }
            if tables.is_empty() {
                tables = vec![Vec::with_capacity(rows.len()); want];
            }
            for (j, f) in fields.iter().enumerate() {
                let v: f64 = f.parse().map_err(|_| GcsArrayError::BadRow {
                    line: *line,
                    problem: format!(
                        "value {} (table {}): expected a number, found `{f}`",
                        j + 1,
                        j + 1
                    ),
                })?;
                tables[j].push(v);
            }
        }
        if let Some(d) = dim {
            if tables.is_empty() {
                tables = vec![Vec::new(); d];
            }
        }
        let found_rows = tables.first().map_or(0, |t| t.len());
        if let Some(n) = ndata {
            if n != found_rows {
                return Err(GcsArrayError::CountMismatch {
                    key: "NDATA",
                    declared: n,
                    found: found_rows,
                });
            }
        }
        Ok(GcsArray { header, tables })
    }

    /// The 0-based table a user names: a 1-based number, or a table's `NAME<i>` (exact).
    pub fn table_index(&self, spec: &str) -> Option<usize> {
        if let Ok(n) = spec.parse::<usize>() {
            return (n >= 1 && n <= self.tables.len()).then(|| n - 1);
        }
        (0..self.tables.len()).find(|&i| self.name(i) == Some(spec))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_and_rows() {
        let g = GcsArray::parse(
            "# VERSION = 1 \n# SEPARATOR = 44 \n# DIM = 2 \n# NDATA = 2 \n# \n# END_HEADER \n1.0,2.0 \n3.0,4.5\n",
        )
        .unwrap();
        assert_eq!(g.tables, vec![vec![1.0, 3.0], vec![2.0, 4.5]]);
        assert_eq!(g.get("VERSION"), Some("1"));
    }

    #[test]
    fn errors_name_the_line() {
        let e = GcsArray::parse("# DIM = 2\n# END_HEADER\n1 2\n3\n").unwrap_err();
        assert_eq!(
            e.to_string(),
            "line 4: expected 2 values (DIM), found 1: `3`"
        );
        let e = GcsArray::parse("# DIM = two\n# END_HEADER\n").unwrap_err();
        assert!(e.to_string().starts_with("line 1: header `DIM`"), "{e}");
        let e = GcsArray::parse("# DIM = 1\n1\n").unwrap_err();
        assert!(
            e.to_string().starts_with("line 2: expected a `# KEY"),
            "{e}"
        );
        let e = GcsArray::parse("# DIM = 1\n# END_HEADER\n1\nx\n").unwrap_err();
        assert!(e.to_string().starts_with("line 4: value 1"), "{e}");
        let e = GcsArray::parse("# DIM = 1\n").unwrap_err();
        assert_eq!(e, GcsArrayError::NoEndHeader(1));
        let e = GcsArray::parse("# NDATA = 3\n# END_HEADER\n1\n").unwrap_err();
        assert!(matches!(
            e,
            GcsArrayError::CountMismatch { key: "NDATA", .. }
        ));
    }
}
