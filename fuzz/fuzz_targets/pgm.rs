//! PGM image decoder (image folders, the camera simulator's `/snapshot.pgm`): never panics,
//! never allocates more than the header's pixel count allows, and what it decodes re-encodes
//! to an image that decodes to the same pixels.
#![no_main]

use libfuzzer_sys::fuzz_target;
use robocal_drivers::camera::pgm;

fuzz_target!(|data: &[u8]| {
    if let Ok((w, h, px)) = pgm::decode(data) {
        assert_eq!(px.len() as u64, w as u64 * h as u64);
        let again = pgm::encode(w, h, &px);
        let (w2, h2, px2) = pgm::decode(&again).expect("re-encoded image decodes");
        assert_eq!((w2, h2), (w, h));
        assert_eq!(px2, px);
    }
});
