//! What robocal file a text is, from its `format` tag: the one helper every reader calls when
//! a file fails to parse as the kind it expected, so that a dataset passed as `--calibration`
//! (or a calibration passed as `--data`) is named as such instead of "invalid JSON".
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
    let tag = format_tag(text)?;
    if tag == expected {
        return None;
    }
    let got = describe(&tag).map_or_else(
        || format!("a `{tag}` file"),
        |d| format!("{d}, format `{tag}`"),
    );
    let want = describe(expected).unwrap_or(expected);
    Some(format!(
        "this is {got}, not {want}: check which file went to which option"
    ))
}

/// `msg`, followed by [`other_kind`]'s sentence when there is one.
pub fn with_other_kind(msg: impl std::fmt::Display, text: &str, expected: &str) -> String {
    match other_kind(text, expected) {
        Some(k) => format!("{k} ({msg})"),
        None => msg.to_string(),
    }
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
}
