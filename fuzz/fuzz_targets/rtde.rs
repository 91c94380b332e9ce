//! RTDE decoders (both directions, data fields): any bytes give packages or errors, never a
//! panic; a decoded package re-encodes to bytes that decode to the same package.
#![no_main]

use bytes::BytesMut;
use libfuzzer_sys::fuzz_target;
use robocal_drivers::ur::rtde::codec::{
    decode_fields, encode_reply, encode_request, ClientCodec, ServerCodec,
};
use robocal_drivers::ur::rtde::frame::DataType;
use tokio_util::codec::Decoder;

fuzz_target!(|data: &[u8]| {
    let mut b = BytesMut::from(data);
    while let Ok(Some(r)) = ClientCodec.decode(&mut b) {
        let mut out = BytesMut::new();
        if encode_reply(&r, &mut out).is_ok() {
            assert_eq!(ClientCodec.decode(&mut out).ok().flatten(), Some(r));
        }
    }
    let mut b = BytesMut::from(data);
    while let Ok(Some(r)) = ServerCodec.decode(&mut b) {
        let mut out = BytesMut::new();
        if encode_request(&r, &mut out).is_ok() {
            let back = ServerCodec.decode(&mut out).ok().flatten();
            // NaN frequencies do not compare equal; everything else must round-trip.
            if !format!("{r:?}").contains("NaN") {
                assert_eq!(back, Some(r));
            }
        }
    }
    if let Some((&n, rest)) = data.split_first() {
        let types: Vec<DataType> = (0..(n % 16) as usize)
            .map(|i| DataType::ALL[(i * 7 + n as usize) % DataType::ALL.len()])
            .collect();
        let _ = decode_fields(&types, rest);
    }
});
