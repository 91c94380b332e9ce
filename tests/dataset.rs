//! `robocal-dataset/1` and `robocal-calibration/1` reader, writer and journal (issue 2).
use std::io::Write as _;
use std::path::{Path, PathBuf};

use robocal::dataset::{
    read_dataset, CalParam, CalibrationFile, CalibrationKind, Dataset, DatasetError, EventRecord,
    Journal, LoadWarning, MarkerObs, PoseRecord, Record, Summary,
};
use serde_json::{json, Map, Value};

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data")
}

fn all_datasets() -> Vec<PathBuf> {
    let mut out = Vec::new();
    for case in std::fs::read_dir(data_dir()).unwrap() {
        let case = case.unwrap().path();
        if !case.is_dir() {
            continue;
        }
        for f in std::fs::read_dir(&case).unwrap() {
            let f = f.unwrap().path();
            if f.extension().is_some_and(|e| e == "jsonl") {
                out.push(f);
            }
        }
    }
    out.sort();
    out
}

/// A small valid dataset text: header + `n` pose lines (ids 0..n), each ending in `\n`.
fn small_text(n: usize) -> String {
    let mut s = String::from(
        r#"{"format": "robocal-dataset/1", "created": "2026-11-21T09:30:00Z", "robot": {"model": "denso-vs060"}}"#,
    );
    s.push('\n');
    for i in 0..n {
        s.push_str(&pose_line(i as u64));
        s.push('\n');
    }
    s
}

fn pose_line(id: u64) -> String {
    format!(
        r#"{{"kind": "pose", "id": {id}, "t": {t}, "group": "train", "q": [10.0, -20.0, 95.0, 0.0, 30.0, {id}.5], "marker": {{"p": [-102.44, 87.13, -1503.92], "quat": [0.5, 0.5, -0.5, 0.5], "rms": 0.08, "visible": true, "frames": 30}}}}"#,
        t = id as f64 * 9.0
    )
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn load_err(text: &str) -> DatasetError {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "train.jsonl", text);
    read_dataset(&p).expect_err("must not load")
}

#[test]
fn every_test_dataset_loads() {
    let files = all_datasets();
    assert!(
        files.len() >= 6,
        "expected the shared datasets, found {files:?}"
    );
    for f in &files {
        let loaded = read_dataset(f).unwrap_or_else(|e| panic!("{e}"));
        assert!(
            loaded.warnings.is_empty(),
            "{}: {:?}",
            f.display(),
            loaded.warnings
        );
        let ds = &loaded.dataset;
        assert_eq!(ds.header.format, "robocal-dataset/1");
        assert_eq!(ds.dof(), Some(6));
        assert!(ds.poses().count() > 0, "{}", f.display());
        let len = std::fs::metadata(f).unwrap().len();
        assert_eq!(loaded.valid_len, len);
    }
    let kin = Dataset::load(data_dir().join("kin-geometric/train.jsonl")).unwrap();
    assert_eq!(kin.poses().count(), 500);
    assert_eq!(kin.poses_in("train").count(), 500);
    let held = Dataset::load(data_dir().join("kin-geometric/heldout.jsonl")).unwrap();
    assert_eq!(held.poses_in("validation").count(), 150);
    let first = held.poses().next().unwrap();
    assert_eq!(first.id, 3);
    assert_eq!(first.q.as_ref().unwrap()[0], -13.27411);
    let laser = Dataset::load(data_dir().join("laser-planes/train.jsonl")).unwrap();
    let p0 = laser.poses().next().unwrap();
    assert!(p0.q.is_none());
    assert_eq!(p0.range, Some(Some(483.5775)));
    assert_eq!(p0.plane.as_deref(), Some("P1"));
    assert_eq!(p0.move_kind.as_deref(), Some("translate"));
    // `block` is not in the contract: it is kept as an unknown field.
    assert_eq!(p0.extra.get("block"), Some(&json!(0)));
}

#[test]
fn test_datasets_round_trip_unchanged() {
    for f in all_datasets() {
        let ds = Dataset::load(&f).unwrap();
        let text = ds.to_jsonl();
        let again = robocal::dataset::parse_dataset(text.as_bytes(), &f).unwrap();
        assert_eq!(again.dataset, ds, "{}", f.display());
        // Values (not only types) survive: compare line by line as JSON.
        let orig = std::fs::read_to_string(&f).unwrap();
        for (a, b) in orig.lines().zip(text.lines()) {
            let a: Value = serde_json::from_str(a).unwrap();
            let b: Value = serde_json::from_str(b).unwrap();
            assert_eq!(normalise(a), normalise(b), "{}", f.display());
        }
    }
}

/// Every f64 the writer prints reads back bit for bit (serde_json `float_roundtrip`): a
/// re-saved dataset or calibration never drifts in the last digit.
#[test]
fn floats_round_trip_bit_exact() {
    let vals = [
        0.1 + 0.2,
        1.0 / 3.0,
        123.456_789_012_345_68,
        -2.2250738585072014e-308,
        9_007_199_254_740_993.0,
        std::f64::consts::PI * 1e-7,
        5e-324,
    ];
    for v in vals {
        let text = serde_json::to_string(&v).unwrap();
        let back: f64 = serde_json::from_str(&text).unwrap();
        assert_eq!(back.to_bits(), v.to_bits(), "{v:e} -> {text}");
    }
    let mut rng = 0x9e37_79b9_7f4a_7c15_u64;
    for _ in 0..20_000 {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        let v = f64::from_bits(rng);
        if !v.is_finite() {
            continue;
        }
        let back: f64 = serde_json::from_str(&serde_json::to_string(&v).unwrap()).unwrap();
        assert_eq!(back.to_bits(), v.to_bits(), "{v:e}");
    }
}

/// Numbers compared as f64 (the writer prints `0` as `0.0`), `visible` defaulted.
fn normalise(v: Value) -> Value {
    match v {
        Value::Number(n) => json!(n.as_f64().unwrap()),
        Value::Array(a) => Value::Array(a.into_iter().map(normalise).collect()),
        Value::Object(o) => {
            let mut m: Map<String, Value> = o.into_iter().map(|(k, v)| (k, normalise(v))).collect();
            if m.contains_key("frames") && !m.contains_key("visible") {
                m.insert("visible".into(), json!(true));
            }
            Value::Object(m)
        }
        other => other,
    }
}

#[test]
fn unknown_fields_survive_read_write() {
    let text = concat!(
        r#"{"format": "robocal-dataset/1", "robot": {"model": "ur5e", "cell": "B2", "chain": null}, "operator": {"name": "kim"}}"#,
        "\n",
        r#"{"kind": "pose", "id": 1, "t": 0.5, "q": [1, 2, 3, 4, 5, 6], "humidity": 41, "marker": {"p": [1, 2, 3], "quat": [1, 0, 0, 0], "markers_seen": 4}, "range": null}"#,
        "\n",
        r#"{"kind": "pivot", "t": 1.0, "tool": "probe", "marker": {"p": [1, 2, 3], "quat": [1, 0, 0, 0]}, "station": 2}"#,
        "\n",
        r#"{"kind": "event", "t": 2.0, "what": "note", "reason": "door opened", "by": "kim"}"#,
        "\n",
    );
    let dir = tempfile::tempdir().unwrap();
    let src = write(dir.path(), "in.jsonl", text);
    let ds = Dataset::load(&src).unwrap();
    let out = dir.path().join("out.jsonl");
    ds.save(&out).unwrap();
    let back = Dataset::load(&out).unwrap();
    assert_eq!(back, ds);
    assert_eq!(back.header.extra["operator"], json!({"name": "kim"}));
    assert_eq!(back.header.robot.extra["cell"], json!("B2"));
    let Record::Pose(p) = &back.records[0] else {
        panic!()
    };
    assert_eq!(p.extra["humidity"], json!(41));
    assert_eq!(p.marker.as_ref().unwrap().extra["markers_seen"], json!(4));
    // `range: null` (out of range) stays distinct from an absent range.
    assert_eq!(p.range, Some(None));
    assert!(std::fs::read_to_string(&out)
        .unwrap()
        .contains("\"range\":null"));
    let Record::Pivot(pv) = &back.records[1] else {
        panic!()
    };
    assert_eq!(pv.extra["station"], json!(2));
    let Record::Event(e) = &back.records[2] else {
        panic!()
    };
    assert_eq!(e.extra["by"], json!("kim"));
}

#[test]
fn torn_last_line_is_dropped_with_a_warning() {
    let mut text = small_text(3);
    let torn = pose_line(3);
    text.push_str(&torn[..torn.len() / 2]);
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "run.jsonl", &text);
    let loaded = read_dataset(&p).unwrap();
    assert_eq!(loaded.dataset.poses().count(), 3);
    assert_eq!(loaded.warnings.len(), 1);
    let LoadWarning::TornLastLine { line, bytes, .. } = &loaded.warnings[0] else {
        panic!()
    };
    assert_eq!(*line, 5);
    assert_eq!(*bytes, torn.len() / 2);
    assert_eq!(loaded.valid_len as usize, small_text(3).len());
    assert!(loaded.warnings[0].to_string().contains("run.jsonl:5"));
}

#[test]
fn torn_line_cut_inside_a_multibyte_character_is_dropped() {
    let mut bytes = small_text(1).into_bytes();
    let line = r#"{"kind": "event", "t": 3.0, "what": "note", "reason": "°C"#;
    let cut = line.as_bytes();
    bytes.extend_from_slice(&cut[..cut.len() - 2]); // half of '°' and nothing after
    let loaded = robocal::dataset::parse_dataset(&bytes, Path::new("x.jsonl")).unwrap();
    assert_eq!(loaded.dataset.records.len(), 1);
    assert_eq!(loaded.warnings.len(), 1);
}

#[test]
fn complete_last_line_without_newline_is_kept() {
    let mut text = small_text(2);
    text.push_str(&pose_line(2));
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "run.jsonl", &text);
    let loaded = read_dataset(&p).unwrap();
    assert_eq!(loaded.dataset.poses().count(), 3);
    assert!(loaded.warnings.is_empty());
}

#[test]
fn bad_line_in_the_middle_is_an_error_naming_file_line_and_field() {
    let mut text = small_text(1);
    text.push_str(r#"{"kind": "pose", "id": 5, "t": 1.0, "q": [10.0, -20.0, 95.0, 0.0, 30.0]}"#);
    text.push('\n');
    text.push_str(&pose_line(6));
    text.push('\n');
    let e = load_err(&text);
    let msg = e.to_string();
    assert!(
        msg.contains("train.jsonl:3: field \"q\": expected an array of 6 numbers"),
        "{msg}"
    );
    assert_eq!(e.line(), Some(3));
    assert_eq!(e.field(), Some("q"));
}

#[test]
fn invalid_json_is_an_error_unless_it_is_a_torn_last_line() {
    // Broken line followed by more lines.
    let mut text = small_text(1);
    text.push_str("{\"kind\": \"pose\", \"id\": 5,\n");
    text.push_str(&pose_line(6));
    text.push('\n');
    let e = load_err(&text);
    assert_eq!(e.line(), Some(3), "{e}");
    assert!(e.to_string().contains("invalid JSON"), "{e}");
    // Broken last line that HAS its newline: not a torn write, an error.
    let mut text = small_text(1);
    text.push_str("{\"kind\": \"pose\", \"id\": 5,\n");
    let e = load_err(&text);
    assert_eq!(e.line(), Some(3), "{e}");
    // An empty line in the middle.
    let mut text = small_text(1);
    text.push('\n');
    text.push_str(&pose_line(6));
    text.push('\n');
    let e = load_err(&text);
    assert!(e.to_string().contains("train.jsonl:3: empty line"), "{e}");
}

#[test]
fn strict_field_checks() {
    let cases: &[(&str, &str, &str)] = &[
        (
            r#"{"kind": "pose", "id": 1, "t": 0, "q": [1, 2, 3, 4, 5, "6"]}"#,
            "q",
            "expected an array of 6 numbers",
        ),
        (
            r#"{"kind": "pose", "id": 1, "t": 0, "q_cmd": [1, 2, 3, 4, 5, 6, 7], "q": [1, 2, 3, 4, 5, 6]}"#,
            "q_cmd",
            "expected an array of 6 numbers",
        ),
        (
            r#"{"kind": "pose", "id": 1, "t": "late", "q": [1, 2, 3, 4, 5, 6]}"#,
            "t",
            "expected a number",
        ),
        (
            r#"{"kind": "pose", "id": -1, "t": 0, "q": [1, 2, 3, 4, 5, 6]}"#,
            "id",
            "expected a non-negative integer",
        ),
        (
            r#"{"kind": "pose", "id": 1, "q": [1, 2, 3, 4, 5, 6]}"#,
            "t",
            "missing",
        ),
        (r#"{"kind": "pose", "id": 1, "t": 0}"#, "q", "missing"),
        (
            r#"{"kind": "pose", "id": 1, "t": 0, "q": [1, 2, 3, 4, 5, 6], "marker": {"p": [1, 2, 3], "quat": [0.9, 0, 0, 0]}}"#,
            "marker.quat",
            "must be unit",
        ),
        (
            r#"{"kind": "pose", "id": 1, "t": 0, "flange": {"p": [1, 2, 3], "quat": [1, 0, 0, 0.1]}}"#,
            "flange.quat",
            "must be unit",
        ),
        (
            r#"{"kind": "pose", "id": 1, "t": 0, "flange": {"p": [1, 2], "quat": [1, 0, 0, 0]}}"#,
            "flange.p",
            "expected an array of 3 numbers",
        ),
        (
            r#"{"kind": "pose", "id": 1, "t": 0, "q": [1, 2, 3, 4, 5, 6], "marker": {"visible": true}}"#,
            "marker.p",
            "missing",
        ),
        (
            r#"{"kind": "pose", "id": 1, "t": 0, "q": [1, 2, 3, 4, 5, 6], "marker": {"p": [1, 2, 3], "visible": "yes"}}"#,
            "marker.visible",
            "expected true or false",
        ),
        (
            r#"{"kind": "pose", "id": 1, "t": 0, "q": [1, 2, 3, 4, 5, 6], "range": "far"}"#,
            "range",
            "expected a number or null",
        ),
        (
            r#"{"kind": "pose", "id": 1, "t": 0, "q": [1, 2, 3, 4, 5, 6], "corners": [[1, 2], [3]]}"#,
            "corners",
            "pairs",
        ),
        (
            r#"{"kind": "pose", "id": 0, "t": 0, "q": [1, 2, 3, 4, 5, 6]}"#,
            "id",
            "pose id 0 is recorded twice",
        ),
        (
            r#"{"kind": "pivot", "t": 0, "marker": {"quat": [1, 0, 0, 0]}}"#,
            "marker.p",
            "missing",
        ),
        (
            r#"{"kind": "event", "t": 0, "what": "explode"}"#,
            "what",
            "unknown event \"explode\"",
        ),
        (
            r#"{"kind": "photo", "t": 0}"#,
            "kind",
            "unknown record kind \"photo\"",
        ),
    ];
    for (line, field, msg) in cases {
        let mut text = small_text(1);
        text.push_str(line);
        text.push('\n');
        let e = load_err(&text);
        assert_eq!(e.line(), Some(3), "{line}: {e}");
        assert_eq!(e.field(), Some(*field), "{line}: {e}");
        assert!(e.to_string().contains(msg), "{line}: {e}");
        assert!(e.to_string().contains("train.jsonl:3: field"), "{e}");
    }
}

#[test]
fn header_checks() {
    let e = load_err("");
    assert!(e.to_string().contains("empty file"), "{e}");
    let e = load_err("{\"format\": \"robocal-dataset/2\", \"robot\": {\"model\": \"ur5e\"}}\n");
    assert_eq!((e.line(), e.field()), (Some(1), Some("format")), "{e}");
    let e = load_err("{\"format\": \"robocal-dataset/1\"}\n");
    assert_eq!(e.field(), Some("robot"), "{e}");
    let e = load_err("{\"format\": \"robocal-dataset/1\", \"robot\": {\"model\": \"kuka\"}}\n");
    assert_eq!(e.field(), Some("robot.model"), "{e}");
    let e = load_err(concat!(
        r#"{"format": "robocal-dataset/1", "robot": {"model": "x", "chain": ["#,
        r#"{"name": "j1", "origin_xyz": [0, 0, 1], "origin_rpy": [0, 0, 0], "axis": [0, 0, 2]}]}}"#,
        "\n"
    ));
    assert_eq!(e.field(), Some("robot.chain[0].axis"), "{e}");
    let e = load_err(concat!(
        r#"{"format": "robocal-dataset/1", "robot": {"model": "x", "chain": ["#,
        r#"{"name": "j1", "origin_xyz": [0, 0], "origin_rpy": [0, 0, 0], "axis": [0, 0, 1]}]}}"#,
        "\n"
    ));
    assert_eq!(e.field(), Some("robot.chain[0].origin_xyz"), "{e}");
    // A header that is only torn is not a dataset.
    let e = load_err("{\"format\": \"robocal-dataset/1\", \"rob");
    assert_eq!(e.line(), Some(1), "{e}");
    // A one-joint chain sets dof = 1 for the records.
    let text = concat!(
        r#"{"format": "robocal-dataset/1", "robot": {"model": "rail", "chain": ["#,
        r#"{"name": "j1", "origin_xyz": [0, 0, 1], "origin_rpy": [0, 0, 0], "axis": [1, 0, 0]}]}}"#,
        "\n",
        r#"{"kind": "pose", "id": 0, "t": 0, "q": [12.5]}"#,
        "\n"
    );
    let ds = robocal::dataset::parse_dataset(text.as_bytes(), Path::new("rail.jsonl")).unwrap();
    assert_eq!(ds.dataset.dof(), Some(1));
}

fn header() -> robocal::dataset::Header {
    let text = small_text(0);
    robocal::dataset::parse_dataset(text.as_bytes(), Path::new("h"))
        .unwrap()
        .dataset
        .header
}

fn pose(id: u64) -> Record {
    let v: Value = serde_json::from_str(&pose_line(id)).unwrap();
    serde_json::from_value(v).unwrap()
}

#[test]
fn journal_appends_whole_lines_and_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dataset.jsonl");
    let mut j = Journal::create(&path, &header()).unwrap();
    for id in 0..5 {
        j.append(&pose(id)).unwrap();
        // Every append is on disk, whole, before append returns.
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.ends_with('\n'));
        assert_eq!(text.lines().count(), id as usize + 2);
        assert_eq!(
            read_dataset(&path).unwrap().dataset.poses().count(),
            id as usize + 1
        );
    }
    j.append(&Record::Event(EventRecord {
        t: 50.0,
        what: "skip".into(),
        id: Some(5),
        reason: Some("marker not visible after 3 tries".into()),
        extra: Map::new(),
    }))
    .unwrap();
    assert_eq!(j.lines(), 7);
    assert_eq!(j.last_pose_id(), Some(4));
    let ds = j.read_back().unwrap();
    assert_eq!(ds.records.len(), 6);
    assert_eq!(ds.records[0], pose(0));
    // Creating over an existing journal is refused.
    assert!(Journal::create(&path, &header()).is_err());
}

#[test]
fn journal_refuses_records_the_reader_would_reject() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dataset.jsonl");
    let mut j = Journal::create(&path, &header()).unwrap();
    j.append(&pose(3)).unwrap();
    let before = std::fs::read(&path).unwrap();
    // Id not increasing.
    let e = j.append(&pose(3)).unwrap_err();
    assert_eq!(e.field(), Some("id"), "{e}");
    // Wrong dof.
    let Record::Pose(mut p) = pose(4) else {
        panic!()
    };
    p.q = Some(vec![1.0, 2.0]);
    let e = j.append(&Record::Pose(p.clone())).unwrap_err();
    assert_eq!(e.field(), Some("q"), "{e}");
    assert!(e.to_string().contains("dataset.jsonl:3"), "{e}");
    // Non-unit quaternion.
    p.q = Some(vec![0.0; 6]);
    p.marker = Some(MarkerObs {
        p: Some([0.0; 3]),
        quat: Some([2.0, 0.0, 0.0, 0.0]),
        rms: None,
        visible: true,
        frames: None,
        extra: Map::new(),
    });
    assert!(j.append(&Record::Pose(p)).is_err());
    assert_eq!(std::fs::read(&path).unwrap(), before, "nothing written");
    j.append(&pose(4)).unwrap();
    assert_eq!(j.read_back().unwrap().poses().count(), 2);
}

#[test]
fn journal_reopen_after_torn_write_truncates_and_continues() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dataset.jsonl");
    {
        let mut j = Journal::create(&path, &header()).unwrap();
        for id in 0..3 {
            j.append(&pose(id)).unwrap();
        }
    }
    // Simulate a power cut in the middle of the 4th write.
    let line = pose_line(3);
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .open(&path)
        .unwrap();
    f.write_all(&line.as_bytes()[..40]).unwrap();
    drop(f);
    let (mut j, loaded) = Journal::open(&path).unwrap();
    assert_eq!(loaded.warnings.len(), 1);
    assert_eq!(loaded.dataset.poses().count(), 3);
    assert_eq!(j.last_pose_id(), Some(2));
    // The torn bytes are gone from the file itself.
    assert!(std::fs::read_to_string(&path).unwrap().ends_with("}\n"));
    // The id order is remembered across the reopen.
    assert!(j.append(&pose(2)).is_err());
    j.append(&pose(3)).unwrap();
    j.append(&pose(4)).unwrap();
    let loaded = read_dataset(&path).unwrap();
    assert!(loaded.warnings.is_empty());
    let ids: Vec<u64> = loaded.dataset.poses().map(|p| p.id).collect();
    assert_eq!(ids, vec![0, 1, 2, 3, 4]);
}

#[test]
fn journal_reopen_when_last_line_lacks_only_its_newline() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dataset.jsonl");
    let mut text = small_text(2);
    text.push_str(&pose_line(2));
    std::fs::write(&path, text).unwrap();
    let (mut j, loaded) = Journal::open(&path).unwrap();
    assert!(loaded.warnings.is_empty());
    j.append(&pose(3)).unwrap();
    let ids: Vec<u64> = Dataset::load(&path)
        .unwrap()
        .poses()
        .map(|p| p.id)
        .collect();
    assert_eq!(ids, vec![0, 1, 2, 3]);
}

#[test]
fn journal_open_or_create() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("dataset.jsonl");
    let (mut j, recs, w) = Journal::open_or_create(&path, &header()).unwrap();
    assert!(recs.is_empty() && w.is_empty());
    j.append(&pose(0)).unwrap();
    drop(j);
    let (_, recs, _) = Journal::open_or_create(&path, &header()).unwrap();
    assert_eq!(recs.len(), 1);
    // Crash while writing the header: only a torn header is on disk → recreated.
    std::fs::write(&path, "{\"format\": \"robocal-data").unwrap();
    let (mut j, recs, _) = Journal::open_or_create(&path, &header()).unwrap();
    assert!(recs.is_empty());
    j.append(&pose(0)).unwrap();
    assert_eq!(Dataset::load(&path).unwrap().poses().count(), 1);
    // A corrupt journal (bad line in the middle) is an error, never silently rewritten.
    let mut text = small_text(1);
    text.push_str("garbage\n");
    text.push_str(&pose_line(5));
    text.push('\n');
    std::fs::write(&path, &text).unwrap();
    assert!(Journal::open_or_create(&path, &header()).is_err());
    assert_eq!(std::fs::read_to_string(&path).unwrap(), text);
}

fn cal_text() -> String {
    let robot = Dataset::load(data_dir().join("kin-geometric/train.jsonl"))
        .unwrap()
        .header
        .robot;
    let mut cal = CalibrationFile::new(
        robot,
        vec![
            CalParam {
                name: "a2".into(),
                value: 0.012, // a 12 µm correction of the nominal a2 = 0 (a plausible calibration: `save` checks it)
                std: Some(0.004),
                unit: "mm".into(),
                free: true,
                extra: Map::new(),
            },
            CalParam {
                name: "phi3".into(),
                value: -89.99,
                std: None,
                unit: "deg".into(),
                free: false,
                extra: Map::new(),
            },
        ],
    );
    cal.metrics.insert("train_rms_mm".into(), json!(0.091));
    cal.extra.insert("solver".into(), json!({"iterations": 7}));
    cal.to_json_pretty()
}

#[test]
fn calibration_round_trip_and_kind() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "cal.json", &cal_text());
    let cal = CalibrationFile::load(&p).unwrap();
    assert_eq!(cal.kind(), CalibrationKind::Kinematic);
    assert_eq!(cal.param("a2").unwrap().std, Some(0.004));
    assert_eq!(cal.robot.dof(), Some(6));
    let out = dir.path().join("out.json");
    cal.save(&out).unwrap();
    let back = CalibrationFile::load(&out).unwrap();
    assert_eq!(back, cal);
    assert_eq!(back.extra["solver"], json!({"iterations": 7}));
    let mut laser = back.clone();
    laser.set_kind("laser");
    laser.save(&out).unwrap();
    assert_eq!(
        CalibrationFile::load(&out).unwrap().kind(),
        CalibrationKind::Laser
    );
}

#[test]
fn calibration_strict_errors_name_file_and_field() {
    let dir = tempfile::tempdir().unwrap();
    let base: Value = serde_json::from_str(&cal_text()).unwrap();
    type Edit = Box<dyn Fn(&mut Value)>;
    let cases: Vec<(Edit, &str)> = vec![
        (
            Box::new(|v| v["params"][1]["value"] = json!("0.01")),
            "params[1].value",
        ),
        (
            Box::new(|v| v["params"][0]["unit"] = json!(null)),
            "params[0].unit",
        ),
        (
            Box::new(|v| {
                v["params"][0].as_object_mut().unwrap().remove("free");
            }),
            "params[0].free",
        ),
        (
            Box::new(|v| v["params"][1]["name"] = json!("a2")),
            "params[1].name",
        ),
        (
            Box::new(|v| v["format"] = json!("robocal-calibration/9")),
            "format",
        ),
        (Box::new(|v| v["params"] = json!({})), "params"),
        (
            Box::new(|v| v["effects"] = json!([{"kind": "backlash", "joint": 7}])),
            "effects[0].joint",
        ),
        (
            Box::new(|v| v["effects"] = json!([{"joint": 2}])),
            "effects[0].kind",
        ),
        (Box::new(|v| v["metrics"] = json!([1])), "metrics"),
        (
            Box::new(|v| v["robot"]["chain"][2]["axis"] = json!([0, 1])),
            "robot.chain[2].axis",
        ),
    ];
    for (edit, field) in cases {
        let mut v = base.clone();
        edit(&mut v);
        let p = write(
            dir.path(),
            "cal.json",
            &serde_json::to_string_pretty(&v).unwrap(),
        );
        let e = CalibrationFile::load(&p).unwrap_err();
        assert_eq!(e.field(), Some(field), "{e}");
        assert!(e.to_string().contains("cal.json: field"), "{e}");
    }
    // Invalid JSON names the line.
    let p = write(
        dir.path(),
        "cal.json",
        "{\n \"format\": \"robocal-calibration/1\",\n oops\n}",
    );
    let e = CalibrationFile::load(&p).unwrap_err();
    assert_eq!(e.line(), Some(3), "{e}");
    assert!(
        e.to_string().starts_with(&format!("{}:3", p.display())),
        "{e}"
    );
    // A missing file names the file.
    let e = CalibrationFile::load(dir.path().join("nope.json")).unwrap_err();
    assert!(e.to_string().contains("nope.json"), "{e}");
}

#[test]
fn summary_counts() {
    let laser = read_dataset(data_dir().join("laser-planes/train.jsonl")).unwrap();
    let s = Summary::of(&laser.dataset, vec![]);
    assert_eq!(s.by_kind["pose"], 180);
    assert_eq!(s.range.with_range, 180);
    assert_eq!(s.poses_with_q, 0);
    assert_eq!(s.poses_with_flange, 180);
    assert!(s.joints.is_empty());

    let kin = Dataset::load(data_dir().join("kin-geometric/train.jsonl")).unwrap();
    let s = Summary::of(&kin, vec![]);
    assert_eq!(s.poses_by_group["train"], 500);
    assert_eq!(s.marker.visible, 500);
    assert_eq!(s.joints.len(), 6);
    let chain = kin.header.robot.chain.as_ref().unwrap();
    for (j, c) in s.joints.iter().zip(chain) {
        let [lo, hi] = c.limits.unwrap();
        assert!(
            j.min_deg >= lo && j.max_deg <= hi && j.min_deg < j.max_deg,
            "{j:?}"
        );
    }
    let qs: Vec<f64> = kin.poses().map(|p| p.q.as_ref().unwrap()[1]).collect();
    let lo = qs.iter().cloned().fold(f64::INFINITY, f64::min);
    assert_eq!(s.joints[1].min_deg, lo);

    // Events, invisible markers and out-of-range lasers.
    let mut ds = Dataset {
        header: header(),
        records: vec![pose(0), pose(1)],
    };
    if let Record::Pose(PoseRecord {
        marker: Some(m),
        range,
        ..
    }) = &mut ds.records[1]
    {
        m.visible = false;
        *range = Some(None);
    }
    for what in ["skip", "skip", "fault"] {
        ds.records.push(Record::Event(EventRecord {
            t: 99.0,
            what: what.into(),
            id: None,
            reason: None,
            extra: Map::new(),
        }));
    }
    let s = Summary::of(&ds, vec!["w".into()]);
    assert_eq!(s.marker.visible, 1);
    assert_eq!(s.marker.not_visible, 1);
    assert_eq!(s.range.out_of_range, 1);
    assert_eq!(s.events["skip"], 2);
    assert_eq!(s.events["fault"], 1);
    assert_eq!(s.time_span_s, Some([0.0, 99.0]));
    let text = s.to_string();
    assert!(text.contains("events:   fault 1, skip 2"), "{text}");
    assert!(text.contains("1 out of range"), "{text}");
}
