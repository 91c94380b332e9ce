//! `robocal import` parsers (IPA layout, serial_robots_datasets, generic CSV with a fixed mapping): never panic, and a
//! table they accept becomes a dataset that robocal's strict reader reads back.
#![no_main]

use libfuzzer_sys::fuzz_target;
use robocal::import::generic::{
    parse_csv, AngleUnit, BodyColumns, CsvMapping, LengthUnit, Orientation, TimeUnit,
};
use robocal::import::ipa::{parse_ipa, IpaOptions};
use robocal::import::serial_robots::{parse_serial_robots, SerialRobotsOptions};
use robocal::import::{robot, Imported};

fn reads_back(imp: &Imported) {
    robocal::dataset::parse_dataset(
        imp.dataset.to_jsonl().as_bytes(),
        std::path::Path::new("fuzz.jsonl"),
    )
    .expect("an imported dataset reads back");
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(imp) = parse_ipa(text, "fuzz.csv", &IpaOptions::default()) {
        reads_back(&imp);
    }
    if let Ok(imp) = parse_serial_robots(text, "fuzz.csv", &SerialRobotsOptions::default()) {
        reads_back(&imp);
    }
    let Ok(robot) = robot::resolve("ur10") else {
        return;
    };
    let map = CsvMapping {
        robot,
        joints: (1..=6).map(|i| format!("j{i}")).collect(),
        joint_unit: AngleUnit::Deg,
        marker: BodyColumns {
            pos: vec!["x".into(), "y".into(), "z".into()],
            orientation: Some(Orientation::Euler {
                cols: vec!["a".into(), "b".into(), "c".into()],
                seq: robocal::import::EulerSeq {
                    axes: [2, 1, 0],
                    intrinsic: false,
                },
                unit: AngleUnit::Deg,
            }),
        },
        length_unit: LengthUnit::Mm,
        time: Some(("t".into(), TimeUnit::S)),
        temp: None,
        rms: None,
        reference: None,
        delimiter: b',',
        decimal_comma: false,
        heldout_every: 4,
    };
    if let Ok(imp) = parse_csv(text, "fuzz.csv", &map) {
        reads_back(&imp);
    }
});
