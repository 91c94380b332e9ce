//! Dataset reader (`robocal-dataset/1` JSON Lines) and its plausibility checks: never panic,
//! never hang, and a dataset the strict reader accepts re-encodes to a file that reads back
//! to the same dataset. The diagnosis' own reader must not panic either.
#![no_main]

#[path = "common/mod.rs"]
mod common;

use common::same_json;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let file = Path::new("fuzz.jsonl");
    if let Ok(loaded) = robocal::dataset::parse_dataset(data, file) {
        let ds = &loaded.dataset;
        let _ = robocal::plausible::check_dataset(ds, file);
        let _ = robocal::dataset::Summary::of(ds, Vec::new());
        let again = robocal::dataset::parse_dataset(ds.to_jsonl().as_bytes(), file)
            .expect("a dataset robocal accepted re-encodes to a file robocal reads");
        let (a, b) = (
            serde_json::to_value(&again.dataset.records).expect("records serialise"),
            serde_json::to_value(&ds.records).expect("records serialise"),
        );
        assert!(same_json(&a, &b), "re-read dataset differs");
        assert!(again.warnings.is_empty());
        // The one observation builder (solve, diagnose, predict) never panics on a dataset
        // the reader accepted.
        let dof = ds.header.robot.chain.as_ref().map_or(6, |c| c.len());
        let _ = robocal::solve::obs::observations(ds, dof, robocal::solve::obs::Split::All);
    }
});
