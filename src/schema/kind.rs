//! What robocal file a text is, from its `format` tag: the one helper every reader calls when
//! a file fails to parse as the kind it expected, so that a dataset passed as `--calibration`
//! (or a calibration passed as `--data`) is named as such instead of "invalid JSON". The
//! same for the TOML files robocal reads ([`TomlKind`]): a scenario given where a JSON file was
//! expected, or a JSON file given where a TOML one was ([`toml_reader_hint`]).
use serde_json::Value;

use super::navnet::NAVNET_FORMAT;
use super::*;

/// Every format tag robocal writes, with what it is in words.
const KINDS: &[(&str, &str)] = &[
    (DATASET_FORMAT, "a dataset (JSON Lines, `--data`)"),
    (
        CALIBRATION_FORMAT,
        "a calibration file (`calibration.json`)",
    ),
    (PLAN_FORMAT, "a pose plan (`plan.json`)"),
    (RUN_FORMAT, "a run directory's `run.json`"),
    (SESSION_FORMAT, "a session record (`session.json`)"),
    (
        REGISTRATION_FORMAT,
        "a CT registration (`registration.json`)",
    ),
    (
        ROBOT_WORLD_FORMAT,
        "a robot-world calibration (`robot_world.json`)",
    ),
    (CHAIN_FORMAT, "a navigation error chain (`chain.json`)"),
    (
        CAMERA_REPORT_FORMAT,
        "a camera report (`camera_report.json`)",
    ),
    (RCM_REPORT_FORMAT, "an RCM report (`rcm_report.json`)"),
    (REPORT_FORMAT, "a report (`robocal report --json`)"),
    (DIAGNOSIS_FORMAT, "a diagnosis (`diagnosis.json`)"),
    (RUN_SUMMARY_FORMAT, "a run summary (`summary.json`)"),
    (LASER_REPORT_FORMAT, "a laser report (`laser_report.json`)"),
    (
        SCAN_REPORT_FORMAT,
        "a laser scan report (`scan_report.json`)",
    ),
    (PIVOT_FORMAT, "a pivot calibration (`pivot.json`)"),
    (NAVNET_FORMAT, "a navigation-chain network file"),
];

/// What `tag` is in words (`None` for a tag robocal does not write).
pub fn describe(tag: &str) -> Option<&'static str> {
    KINDS.iter().find(|(t, _)| *t == tag).map(|(_, d)| *d)
}

/// The `format` tag of `text`: that of the whole text as one JSON object (a pretty-printed
/// file), else that of its first non-blank line (a JSON Lines dataset). `None` when neither
/// is a JSON object with a string `format`.
pub fn format_tag(text: &str) -> Option<String> {
    let tag_of = |s: &str| {
        serde_json::from_str::<Value>(s)
            .ok()
            .and_then(|v| v.get("format")?.as_str().map(str::to_string))
    };
    tag_of(text).or_else(|| text.lines().find(|l| !l.trim().is_empty()).and_then(tag_of))
}

/// When `text` is a robocal file of another kind than `expected` (a format tag, or a short
/// description such as "a robot block" for a file without one), the sentence saying what it
/// is; `None` when it carries no `format` tag or the expected one. A reader appends it to its
/// parse error.
pub fn other_kind(text: &str, expected: &str) -> Option<String> {
    let Some(tag) = format_tag(text) else {
        // A robocal TOML file (scenario, plan spec, ...) given to a JSON reader.
        let want = describe(expected).unwrap_or(expected);
        return toml_sentence(text).map(|got| format!("{got}, not {want}: {CHECK}"));
    };
    if tag == expected {
        return None;
    }
    let got = describe(&tag).map_or_else(
        || format!("a `{tag}` file"),
        |d| format!("{d}, format `{tag}`"),
    );
    let want = describe(expected).unwrap_or(expected);
    Some(format!("this is {got}, not {want}: {CHECK}"))
}

const CHECK: &str = "check which file went to which option";

/// The TOML files robocal reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TomlKind {
    /// A simulated cell (`mocks/scenarios/*.toml`, `--sim`, `sim serve --scenario`).
    Scenario,
    /// A plan spec (`plans/*.toml`, `plan --spec`, `session --plan-spec`).
    PlanSpec,
    /// An acceptance spec (`accept/*.toml`, `--accept`).
    AcceptSpec,
    /// A device file (`examples/CELL.toml`, `--devices`).
    DeviceFile,
}

impl TomlKind {
    /// The kind's name alone ("a scenario").
    pub fn name(self) -> &'static str {
        match self {
            TomlKind::Scenario => "a scenario",
            TomlKind::PlanSpec => "a plan spec",
            TomlKind::AcceptSpec => "an accept spec",
            TomlKind::DeviceFile => "a device file",
        }
    }

    /// The kind in words, with where it goes.
    pub fn describe(self) -> &'static str {
        match self {
            TomlKind::Scenario => "a scenario (TOML, `--sim`)",
            TomlKind::PlanSpec => "a plan spec (TOML, `plans/*.toml`)",
            TomlKind::AcceptSpec => "an accept spec (TOML, `--accept`)",
            TomlKind::DeviceFile => "a device file (TOML, `--devices`)",
        }
    }
}

/// Top-level tables that mark each TOML kind, in the order they are tried.
const TOML_MARKS: &[(TomlKind, &[&str])] = &[
    (TomlKind::DeviceFile, &["device"]),
    (TomlKind::Scenario, &["arm", "scene", "operator"]),
    (
        TomlKind::PlanSpec,
        &[
            "constraints",
            "shell",
            "annulus",
            "rcm",
            "planes",
            "validation",
        ],
    ),
];

/// Which robocal TOML file `text` is, judging by its top-level tables and keys, with the
/// tables (or keys) that told; `None` when it is not TOML or none of robocal's.
pub fn toml_kind(text: &str) -> Option<(TomlKind, Vec<String>)> {
    let t: toml::Table = toml::from_str(text).ok()?;
    for (kind, marks) in TOML_MARKS {
        let seen: Vec<String> = t
            .iter()
            .filter(|(k, v)| marks.contains(&k.as_str()) && (v.is_table() || v.is_array()))
            .map(|(k, _)| format!("[{k}]"))
            .collect();
        if !seen.is_empty() {
            return Some((*kind, seen));
        }
    }
    // An accept spec has no tables: a name, the session kind and thresholds `*_max`.
    let keys: Vec<String> = t
        .iter()
        .filter(|(k, v)| {
            !v.is_table() && (k.as_str() == "session" || k.ends_with("_max") || k.ends_with("_min"))
        })
        .map(|(k, _)| format!("`{k}`"))
        .take(3)
        .collect();
    (t.contains_key("name") && !keys.is_empty()).then_some((TomlKind::AcceptSpec, keys))
}

/// "this is a TOML file (a scenario …, judging by its tables [arm], [scene])" for a robocal
/// TOML text.
fn toml_sentence(text: &str) -> Option<String> {
    let (kind, seen) = toml_kind(text)?;
    let what = if seen[0].starts_with('[') {
        "tables"
    } else {
        "keys"
    };
    Some(format!(
        "this is a TOML file ({}, judging by its {what} {})",
        kind.name(),
        seen.join(", ")
    ))
}

/// What a TOML reader expecting `expected` appends to its parse error when `text` is another
/// robocal file: a JSON file with a `format` tag (a calibration given as `--sim`), or a
/// robocal TOML file of another kind (a plan spec given as `--devices`). `None` otherwise.
pub fn toml_reader_hint(text: &str, expected: TomlKind) -> Option<String> {
    let want = expected.describe();
    if let Some(tag) = format_tag(text) {
        let got = describe(&tag).map_or_else(
            || format!("a JSON `{tag}` file"),
            |d| format!("{d}, format `{tag}`"),
        );
        return Some(format!("this is {got}, not {want}: {CHECK}"));
    }
    match toml_kind(text) {
        Some((k, _)) if k != expected => {
            Some(format!("{}, not {want}: {CHECK}", toml_sentence(text)?))
        }
        _ => None,
    }
}

/// `msg`, preceded by [`toml_reader_hint`]'s sentence when there is one.
pub fn with_toml_hint(msg: impl std::fmt::Display, text: &str, expected: TomlKind) -> String {
    prefixed(msg, toml_reader_hint(text, expected))
}

/// `msg` in parentheses after `hint`, or `msg` alone.
fn prefixed(msg: impl std::fmt::Display, hint: Option<String>) -> String {
    match hint {
        Some(k) => format!("{k} ({msg})"),
        None => msg.to_string(),
    }
}

/// `msg`, followed by [`other_kind`]'s sentence when there is one.
pub fn with_other_kind(msg: impl std::fmt::Display, text: &str, expected: &str) -> String {
    prefixed(msg, other_kind(text, expected))
}

#[cfg(test)]
mod tests {
    use super::*;

    const DATASET: &str = "{\"format\":\"robocal-dataset/1\",\"robot\":{\"model\":\"x\"}}\n\
                           {\"kind\":\"pose\",\"id\":0}\n";
    const CAL: &str = "{\n  \"format\": \"robocal-calibration/1\",\n  \"params\": []\n}\n";

    #[test]
    fn a_dataset_is_named_where_a_calibration_was_expected() {
        assert!(serde_json::from_str::<Value>(DATASET).is_err());
        let m = other_kind(DATASET, CALIBRATION_FORMAT).unwrap();
        assert!(
            m.contains("a dataset") && m.contains("robocal-dataset/1"),
            "{m}"
        );
        assert!(m.contains("not a calibration file"), "{m}");
    }

    #[test]
    fn a_pretty_calibration_is_named_where_a_dataset_was_expected() {
        let m = other_kind(CAL, DATASET_FORMAT).unwrap();
        assert!(
            m.contains("a calibration file") && m.contains("not a dataset"),
            "{m}"
        );
        let m = with_other_kind("invalid JSON", CAL, "a robot block");
        assert!(m.starts_with("this is a calibration file") && m.ends_with("(invalid JSON)"));
        assert!(m.contains("not a robot block"), "{m}");
    }

    #[test]
    fn the_expected_kind_or_a_foreign_file_adds_nothing() {
        assert_eq!(other_kind(CAL, CALIBRATION_FORMAT), None);
        assert_eq!(other_kind(DATASET, DATASET_FORMAT), None);
        assert_eq!(other_kind("not json at all", CALIBRATION_FORMAT), None);
        assert_eq!(other_kind("{\"format\": 3}", CALIBRATION_FORMAT), None);
        assert_eq!(with_other_kind("bad", "[1,2", PLAN_FORMAT), "bad");
        let m = other_kind("{\"format\":\"robocal-future/9\"}", PLAN_FORMAT).unwrap();
        assert!(
            m.contains("`robocal-future/9`") && m.contains("pose plan"),
            "{m}"
        );
    }

    #[test]
    fn every_format_tag_declared_in_schema_is_described() {
        // Scans the declarations, so a tag added to `schema/` without a description fails.
        let src = [include_str!("mod.rs"), include_str!("navnet.rs")].concat();
        let tags: Vec<&str> = src
            .lines()
            .filter(|l| l.starts_with("pub const ") && l.contains("_FORMAT: &str = \""))
            .filter_map(|l| l.split('"').nth(1))
            .collect();
        assert!(tags.len() >= 17, "{tags:?}");
        for t in tags {
            assert!(
                describe(t).is_some(),
                "format tag {t} has no description in KINDS"
            );
        }
    }

    const SCENARIO: &str = include_str!("../../mocks/scenarios/hospital-vs060-vega.toml");
    const PLAN_SPEC: &str = include_str!("../../plans/seed004-shell.toml");
    const ACCEPT: &str = include_str!("../../accept/camera.toml");
    const DEVICES: &str = include_str!("../../examples/CELL.toml");

    #[test]
    fn every_shipped_toml_file_is_recognised() {
        assert_eq!(toml_kind(SCENARIO).unwrap().0, TomlKind::Scenario);
        assert_eq!(toml_kind(PLAN_SPEC).unwrap().0, TomlKind::PlanSpec);
        assert_eq!(toml_kind(ACCEPT).unwrap().0, TomlKind::AcceptSpec);
        assert_eq!(toml_kind(DEVICES).unwrap().0, TomlKind::DeviceFile);
        let dirs = ["mocks/scenarios", "plans", "accept", "examples"];
        let want = [
            TomlKind::Scenario,
            TomlKind::PlanSpec,
            TomlKind::AcceptSpec,
            TomlKind::DeviceFile,
        ];
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut n = 0;
        for (dir, kind) in dirs.iter().zip(want) {
            for e in std::fs::read_dir(root.join(dir)).unwrap() {
                let p = e.unwrap().path();
                if p.extension().is_some_and(|x| x == "toml") {
                    let t = std::fs::read_to_string(&p).unwrap();
                    assert_eq!(toml_kind(&t).map(|k| k.0), Some(kind), "{}", p.display());
                    n += 1;
                }
            }
        }
        assert!(n >= 20, "{n} files");
        assert_eq!(toml_kind("not toml at all"), None);
        assert_eq!(toml_kind("a = 1\n[b]\nc = 2\n"), None);
        assert_eq!(toml_kind(CAL), None);
    }

    #[test]
    fn a_toml_file_is_named_where_a_json_file_was_expected() {
        assert!(serde_json::from_str::<Value>(SCENARIO).is_err());
        let m = other_kind(SCENARIO, CALIBRATION_FORMAT).unwrap();
        assert!(
            m.starts_with("this is a TOML file (a scenario")
                && m.contains("judging by its tables [arm]")
                && m.contains("not a calibration file"),
            "{m}"
        );
        let m = other_kind(PLAN_SPEC, DATASET_FORMAT).unwrap();
        assert!(
            m.contains("a plan spec") && m.contains("[constraints]") && m.contains("not a dataset"),
            "{m}"
        );
        let m = with_other_kind("invalid JSON", ACCEPT, PLAN_FORMAT);
        assert!(m.contains("(an accept spec, judging by its keys `"), "{m}");
        assert!(m.ends_with("(invalid JSON)"), "{m}");
        let m = other_kind(DEVICES, CALIBRATION_FORMAT).unwrap();
        assert!(m.contains("a device file") && m.contains("[device]"), "{m}");
    }

    #[test]
    fn a_json_or_another_toml_file_is_named_where_a_toml_file_was_expected() {
        let m = toml_reader_hint(CAL, TomlKind::Scenario).unwrap();
        assert!(
            m.contains("this is a calibration file")
                && m.contains("`robocal-calibration/1`")
                && m.contains("not a scenario"),
            "{m}"
        );
        let m = toml_reader_hint(DATASET, TomlKind::AcceptSpec).unwrap();
        assert!(
            m.contains("a dataset") && m.contains("not an accept spec"),
            "{m}"
        );
        let m = with_toml_hint("unknown field", PLAN_SPEC, TomlKind::DeviceFile);
        assert!(
            m.starts_with("this is a TOML file (a plan spec")
                && m.contains("not a device file")
                && m.ends_with("(unknown field)"),
            "{m}"
        );
        // The expected kind, or nothing robocal knows, adds nothing.
        assert_eq!(toml_reader_hint(SCENARIO, TomlKind::Scenario), None);
        assert_eq!(toml_reader_hint("x = [", TomlKind::PlanSpec), None);
        assert_eq!(with_toml_hint("bad", "x = 1", TomlKind::DeviceFile), "bad");
    }
}
