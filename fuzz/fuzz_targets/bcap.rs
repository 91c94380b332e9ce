//! b-CAP packet / VARIANT decoders: never panic; a decoded packet re-encodes to the same bytes
//! modulo float NaN payloads.
#![no_main]

use bytes::BytesMut;
use libfuzzer_sys::fuzz_target;
use robocal_drivers::bcap::codec::{decode_packet, decode_variant_exact, packet_bytes, BcapCodec};
use tokio_util::codec::Decoder;

fuzz_target!(|data: &[u8]| {
    if let Ok(p) = decode_packet(data) {
        let bytes = packet_bytes(&p).expect("a decoded packet re-encodes");
        // Re-encoding is canonical (BOOL as -1/0); decoding it again gives the same packet.
        let again = decode_packet(&bytes).expect("re-encoded packet decodes");
        if !format!("{p:?}").contains("NaN") {
            assert_eq!(again, p);
        }
    }
    let _ = decode_variant_exact(data);
    let mut b = BytesMut::from(data);
    while let Ok(Some(_)) = BcapCodec.decode(&mut b) {}
});
