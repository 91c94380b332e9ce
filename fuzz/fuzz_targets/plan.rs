//! Plan file reader (`robocal-plan/1`) and the safety re-check of `plan --check` / `run`:
//! never panic; an accepted plan re-encodes to a file that reads back equal.
#![no_main]

#[path = "common/mod.rs"]
mod common;

use common::same_json;
use libfuzzer_sys::fuzz_target;
use robocal::plan::PlanFile;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(plan) = PlanFile::from_json_str(text) {
        let _ = robocal::plan::recheck::recheck(&plan, None);
        let json = serde_json::to_string(&plan).expect("a plan serialises");
        let again = PlanFile::from_json_str(&json)
            .expect("a plan robocal accepted re-encodes to a file robocal reads");
        let (a, b) = (
            serde_json::to_value(&again).expect("serialise"),
            serde_json::to_value(&plan).expect("serialise"),
        );
        assert!(same_json(&a, &b), "re-read plan differs");
    }
});
