//! Recording reader/writer: layout roles, round trip, and errors that name line and column.
use nanocal::recording::{ColumnRole, Recording, RecordingError};

#[test]
fn roles_and_extra_columns() {
    let csv = b"t,cmd_x,meas_x,temp_a,temp_b,pressure,note\r\n0,0,0.1,22,22.5,1013.2,7\r\n\r\n1,30,30.2,22.1,22.4,1013.1,8\r\n";
    let rec = Recording::parse(csv).unwrap();
    assert_eq!(rec.rows(), 2);
    assert_eq!(rec.axes(), vec!["x"]);
    assert_eq!(rec.temp_columns(), vec!["temp_a", "temp_b"]);
    assert_eq!(rec.aux_columns(), vec!["pressure", "note"]);
    assert_eq!(rec.time_s().unwrap(), &[0.0, 1.0]);
    assert_eq!(rec.cmd("x").unwrap(), &[0.0, 30.0]);
    assert_eq!(ColumnRole::of("meas_y"), ColumnRole::Meas("y".into()));
}

#[test]
fn round_trip_is_exact() {
    let vals: Vec<f64> = (0..200)
        .map(|i| (i as f64 * 0.37).sin() * 1e3 + 1.0 / 3.0)
        .collect();
    let rec = Recording::from_columns(vec![
        ("t".into(), (0..200).map(|i| i as f64 * 0.1).collect()),
        ("meas_x".into(), vals),
    ])
    .unwrap();
    let mut buf = Vec::new();
    rec.write(&mut buf).unwrap();
    assert_eq!(Recording::parse(&buf).unwrap(), rec);
}

#[test]
fn missing_value_names_line_and_column() {
    let err = Recording::parse(b"t,meas_x\n0,1\n1,\n").unwrap_err();
    match &err {
        RecordingError::MissingValue { line, column, name } => {
            assert_eq!((*line, *column, name.as_str()), (3, 2, "meas_x"));
        }
        e => panic!("unexpected {e:?}"),
    }
    assert!(err.to_string().contains("line 3"), "{err}");
    let err = Recording::parse(b"t,meas_x,temp_a\n0,1\n").unwrap_err();
    assert!(
        matches!(
            err,
            RecordingError::MissingValue {
                line: 2,
                column: 3,
                ..
            }
        ),
        "{err:?}"
    );
}

#[test]
fn non_numeric_value_names_line_and_column() {
    let err = Recording::parse(b"t,meas_x\n0,1\n1,2\n2,abc\n").unwrap_err();
    assert!(
        matches!(&err, RecordingError::NotNumeric { line: 4, column: 2, found, .. } if found == "abc"),
        "{err:?}"
    );
    assert!(err.to_string().contains("`meas_x`"));
}

#[test]
fn bad_header_and_extra_values_are_rejected() {
    assert!(matches!(Recording::parse(b""), Err(RecordingError::Empty)));
    assert!(matches!(
        Recording::parse(b"t,t\n1,2\n"),
        Err(RecordingError::BadHeader { column: 2, .. })
    ));
    assert!(matches!(
        Recording::parse(b"t,x\n1,2,3\n"),
        Err(RecordingError::TooManyValues { line: 2, .. })
    ));
    let rec = Recording::parse(b"t\n1\n").unwrap();
    let err = rec.require("meas_x").unwrap_err();
    assert!(err.to_string().contains("meas_x") && err.to_string().contains('t'));
}
