//! Acceptance spec reader (`ACCEPT.toml`): never panics; an accepted spec names its session
//! kind, has an accuracy criterion of it, and re-encodes to a spec that reads back equal.
#![no_main]

use libfuzzer_sys::fuzz_target;
use robocal::session::AcceptSpec;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(spec) = AcceptSpec::from_toml_str(text, "fuzz.toml") {
        let kind = spec.session.expect("an accepted spec names its session kind");
        spec.check_kind(kind, "fuzz.toml")
            .expect("a spec judges its own kind");
        let again = toml::to_string(&spec).expect("a spec serialises");
        let back = AcceptSpec::from_toml_str(&again, "fuzz.toml")
            .expect("an accepted spec re-encodes to a spec robocal reads");
        assert_eq!(back, spec, "re-read spec differs");
    }
});
