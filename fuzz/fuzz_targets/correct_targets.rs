//! Target tables of `robocal correct` (`name,x_mm,y_mm,z_mm,qw,qx,qy,qz[,branch]`): never
//! panic; an accepted table has finite positions away from the base origin, unit
//! quaternions and branches 0–7.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let Ok(targets) = robocal::solve::correct::parse_targets("fuzz.csv", text) else {
        return;
    };
    assert!(!targets.is_empty(), "an accepted table has rows");
    for t in &targets {
        let p = t.pose.translation.vector;
        assert!(p.iter().all(|x| x.is_finite()), "finite position");
        assert!((t.pose.rotation.norm() - 1.0).abs() < 1e-9, "unit quaternion");
        assert!(t.branch.is_none_or(|b| b <= 7), "branch 0–7");
    }
});
