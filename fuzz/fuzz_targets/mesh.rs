//! Mesh reader (binary / ASCII STL, PLY) of `register --ct-mesh`: never panics, never
//! allocates from a count the file merely claims.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = robocal::register::mesh::parse_mesh(data, "fuzz.stl");
});
