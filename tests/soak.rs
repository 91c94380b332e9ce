//! A short soak in CI (issue 14): the `acquire_soak` example's checks on both wire cells — the
//! lab (b-CAP arm, DL-RS1A laser on a pty) and the hospital (b-CAP arm, NDI Vega over TCP) —
//! with every wire fault and protective stops injected at random. The full 2,000-pose soak is
//! `cargo run --release --example acquire_soak`.

#[allow(dead_code)]
#[path = "../examples/acquire_soak.rs"]
mod example;

#[test]
fn short_soak_loses_no_pose_and_logs_every_fault_on_both_wire_cells() {
    let mut faults = 0;
    for (k, file) in [
        "mocks/scenarios/lab-vs060-optotrak-il600.toml",
        "mocks/scenarios/hospital-vs060-vega.toml",
    ]
    .iter()
    .enumerate()
    {
        let seed = 700 + k as u64;
        let calm = example::soak(file, 40, 0.0, seed).unwrap_or_else(|e| panic!("{file}: {e:#}"));
        let t = example::soak(file, 40, 0.35, seed).unwrap_or_else(|e| panic!("{file}: {e:#}"));
        println!(
            "{file}: {} of 40 recorded without faults, {} with {} wire faults + {} stops \
             ({} invocations); per kind (consumed, with an event) {:?}",
            calm.recorded, t.recorded, t.injected, t.stops, t.invocations, t.consumed_by_kind
        );
        assert_eq!(
            calm.ids, t.ids,
            "{file}: faults changed which poses are recorded"
        );
        assert!(t.silent.is_empty(), "{file}: {:?}", t.silent);
        assert!(
            calm.recorded > 10,
            "{file}: the cell records too few of the poses"
        );
        faults += t.injected + t.stops;
    }
    assert!(faults >= 10, "only {faults} faults injected");
}
