//! Point tables (`id,x_mm,y_mm,z_mm` and `name,x_mm,y_mm,z_mm`: fiducials, CT targets, the
//! points `capture points` writes): never panic; an accepted named table re-encodes to one
//! that reads back with the same names and points (to the written 1e-6 mm).
#![no_main]

use libfuzzer_sys::fuzz_target;
use robocal::schema::points_csv as pc;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let _ = pc::parse(text, "fuzz.csv");
    let Ok(rows) = pc::parse_named(text, "fuzz.csv") else {
        return;
    };
    let rows: Vec<pc::NamedRow> = rows.into_iter().map(|(r, _)| r).collect();
    let again = pc::parse_named(&pc::named_to_string(&rows), "fuzz.csv")
        .expect("a named table robocal accepted re-encodes to one robocal reads");
    assert_eq!(again.len(), rows.len());
    for ((b, _), a) in again.iter().zip(&rows) {
        assert_eq!(a.name, b.name);
        for (x, y) in [(a.x_mm, b.x_mm), (a.y_mm, b.y_mm), (a.z_mm, b.z_mm)] {
            assert!((x - y).abs() <= 1e-6 * (1.0 + x.abs()), "{x} re-read as {y}");
        }
    }
});
