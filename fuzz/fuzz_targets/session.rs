//! The session record (`session.json`, read by `session --resume`, `report`, `history`):
//! never panics; an accepted file re-encodes to one that reads back equal, and judging it and
//! printing its verify section never panic.
#![no_main]

#[path = "common/mod.rs"]
mod common;

use common::same_json;
use libfuzzer_sys::fuzz_target;
use robocal::session::SessionFile;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(mut s) = serde_json::from_str::<SessionFile>(text) else {
        return;
    };
    let again: SessionFile = serde_json::from_str(
        &serde_json::to_string_pretty(&s).expect("serialise"),
    )
    .expect("a session file robocal accepted re-encodes to one robocal reads");
    let (a, b) = (
        serde_json::to_value(&again).expect("serialise"),
        serde_json::to_value(&s).expect("serialise"),
    );
    assert!(same_json(&a, &b), "re-read session file differs");
    if let Some(v) = &s.verify {
        let _ = robocal::session::verify::line(v);
        let _ = robocal::session::verify::html(v);
    }
    robocal::session::judge_into(&mut s);
});
