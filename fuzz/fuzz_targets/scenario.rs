//! Scenario reader (simulated cells, strict TOML): never panics; every number of an accepted
//! scenario is finite and its motion caps and rates are positive (what keeps the simulated
//! clock and settling loops finite).
#![no_main]

use libfuzzer_sys::fuzz_target;
use robocal_mocks::scenario::Scenario;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(s) = Scenario::from_toml(text) {
        for a in &s.arms {
            assert!(a.motion.settle_s.is_finite() && a.motion.settle_s >= 0.0);
            assert!(a.motion.max_vel_deg_s > 0.0 && a.motion.max_acc_deg_s2 > 0.0);
        }
        for t in &s.trackers {
            assert!(t.rate_hz > 0.0 && t.rate_hz.is_finite());
        }
        let _ = s.devices();
    }
});
