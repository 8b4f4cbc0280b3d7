//! What `nanocal fit` records of where a model comes from (blob format 4,
//! `nanocal_model::provenance`): the stage's serial from its controller's `*IDN?` line, the
//! recording's axis names, µm, the fit's date and the FNV-1a 64 hash of the recording's bytes.

use nanocal_model::provenance::{fnv1a64, serial_of_idn, AxisName, ProvenanceUnit};
use nanocal_model::{Provenance, MAX_AXES};

/// Why the provenance options were refused.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ProvenanceError {
    /// The `*IDN?` line has no serial (third comma-separated field).
    #[error("--stage-idn {line:?}: no serial number in it (expected the controller's *IDN? reply, e.g. \"(c)2015 Physik Instrumente (PI) GmbH & Co. KG, E-727, 0116044408, 13.21.00.09\": the serial is the third comma-separated field, 1 to 24 printable characters)")]
    NoSerial {
        /// The line given.
        line: String,
    },
    /// The fit date is neither UTC seconds nor `YYYY-MM-DD[THH:MM:SS[Z]]`.
    #[error(
        "--fit-date {text:?}: expected UTC seconds since 1970 or YYYY-MM-DD[THH:MM:SS[Z]] (UTC)"
    )]
    BadDate {
        /// The text given.
        text: String,
    },
    /// An axis name does not fit the blob's field.
    #[error("axis name {name:?} does not fit the blob's provenance (1 to 8 printable characters)")]
    BadAxisName {
        /// The name.
        name: String,
    },
}

/// The provenance of a fit on `recording_bytes` with the recording's `axes` (in model order),
/// the controller's identification line `stage_idn` (when known) and the fit date.
pub fn provenance(
    recording_bytes: &[u8],
    axes: &[String],
    stage_idn: Option<&str>,
    fit_date_s: i64,
) -> Result<Provenance, ProvenanceError> {
    let stage_serial = match stage_idn {
        None => None,
        Some(line) => {
            Some(
                serial_of_idn(line.as_bytes()).ok_or_else(|| ProvenanceError::NoSerial {
                    line: line.to_string(),
                })?,
            )
        }
    };
    let mut names = [None; MAX_AXES];
    for (slot, name) in names.iter_mut().zip(axes) {
        *slot = Some(
            AxisName::new(name.as_bytes())
                .ok_or_else(|| ProvenanceError::BadAxisName { name: name.clone() })?,
        );
    }
    Ok(Provenance {
        stage_serial,
        axes: names,
        unit: ProvenanceUnit::Um,
        fit_date_s,
        data_fnv64: fnv1a64(recording_bytes),
    })
}

/// Days since 1970-01-01 of a civil date (H. Hinnant's `days_from_civil`).
fn days_from_civil(y: i64, m: i64, d: i64) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (m + 9) % 12;
    let doy = (153 * mp + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// The civil date of a day count since 1970-01-01 (H. Hinnant's `civil_from_days`).
fn civil_from_days(z: i64) -> (i64, i64, i64) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}

/// `--fit-date`: UTC seconds since 1970, or `YYYY-MM-DD[THH:MM:SS[Z]]` read as UTC.
pub fn parse_fit_date(text: &str) -> Result<i64, ProvenanceError> {
    let bad = || ProvenanceError::BadDate {
        text: text.to_string(),
    };
    if let Ok(s) = text.parse::<i64>() {
        return Ok(s);
    }
    let t = text.strip_suffix('Z').unwrap_or(text);
    let (date, time) = t.split_once('T').unwrap_or((t, "00:00:00"));
    let num = |s: &str, lo: i64, hi: i64| -> Result<i64, ProvenanceError> {
        let v: i64 = s.parse().map_err(|_| bad())?;
        if (lo..=hi).contains(&v) && s.bytes().all(|b| b.is_ascii_digit()) {
            Ok(v)
        } else {
            Err(bad())
        }
    };
    let d: Vec<&str> = date.split('-').collect();
    let h: Vec<&str> = time.split(':').collect();
    if d.len() != 3 || h.len() != 3 || d[0].len() != 4 {
        return Err(bad());
    }
    let (y, mo, day) = (num(d[0], 0, 9999)?, num(d[1], 1, 12)?, num(d[2], 1, 31)?);
    // a day past the month's end is refused, not rolled over
    if civil_from_days(days_from_civil(y, mo, day)) != (y, mo, day) {
        return Err(bad());
    }
    let (hh, mm, ss) = (num(h[0], 0, 23)?, num(h[1], 0, 59)?, num(h[2], 0, 59)?);
    Ok(days_from_civil(y, mo, day) * 86_400 + hh * 3600 + mm * 60 + ss)
}

/// UTC seconds since 1970 as `YYYY-MM-DDTHH:MM:SSZ`.
pub fn format_utc(s: i64) -> String {
    let (y, m, d) = civil_from_days(s.div_euclid(86_400));
    let t = s.rem_euclid(86_400);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        t / 3600,
        t / 60 % 60,
        t % 60
    )
}

/// The provenance in words (one line).
pub fn describe(p: &Provenance) -> String {
    let axes: Vec<&str> = p.axes.iter().flatten().map(|a| a.as_str()).collect();
    format!(
        "provenance: stage serial {}, axes {} in {}, fitted {}, training data FNV-1a 64 {:016x}",
        p.stage_serial.map_or(
            "not recorded (the device will not check the stage)".to_string(),
            |s| s.as_str().to_string()
        ),
        if axes.is_empty() {
            "not recorded".to_string()
        } else {
            axes.join(",")
        },
        p.unit.name(),
        if p.fit_date_s == 0 {
            "at an unknown date".to_string()
        } else {
            format_utc(p.fit_date_s)
        },
        p.data_fnv64
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_read_and_print_as_utc() {
        assert_eq!(parse_fit_date("1700000000").unwrap(), 1_700_000_000);
        assert_eq!(
            parse_fit_date("2023-11-14T22:13:20Z").unwrap(),
            1_700_000_000
        );
        assert_eq!(parse_fit_date("1970-01-01").unwrap(), 0);
        assert_eq!(parse_fit_date("2024-02-29").unwrap(), 1_709_164_800);
        assert_eq!(format_utc(1_700_000_000), "2023-11-14T22:13:20Z");
        for bad in [
            "2023-02-29",
            "2023-13-01",
            "yesterday",
            "2023-11-14T25:00:00",
        ] {
            assert!(parse_fit_date(bad).is_err(), "{bad}");
        }
    }
}
