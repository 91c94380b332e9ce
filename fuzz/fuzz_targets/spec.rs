//! Plan specification reader (`plans/*.toml`): never panics; an accepted spec names a
//! bounded number of targets (what the generator will allocate).
#![no_main]

use libfuzzer_sys::fuzz_target;
use robocal::plan::PlanSpec;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(spec) = PlanSpec::from_toml_str(text) {
        assert!(spec.target_count() <= robocal::plan::spec::MAX_TARGETS);
        assert!(spec.timing.settle_s.is_finite() && spec.timing.sample_s.is_finite());
    }
});
