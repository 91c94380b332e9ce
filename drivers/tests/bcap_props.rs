//! b-CAP decoders: proptest round trips, and ≥ 100,000 random and mutated inputs that must
//! yield errors, never panics, and never an allocation beyond `MAX_PACKET` (measured by a
//! counting global allocator).

use bytes::BytesMut;
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use robocal_drivers::bcap::codec::{
    decode_packet, decode_variant_exact, encode_variant, packet_bytes, BcapCodec,
};
use robocal_drivers::bcap::frame::{func, Packet, Variant, MAX_PACKET};
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use tokio_util::codec::Decoder;

struct Counting;
thread_local! {
    static MAX_ALLOC: Cell<usize> = const { Cell::new(0) };
}
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        let _ = MAX_ALLOC.try_with(|m| m.set(m.get().max(l.size())));
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        let _ = MAX_ALLOC.try_with(|m| m.set(m.get().max(n)));
        unsafe { System.realloc(p, l, n) }
    }
}
#[global_allocator]
static A: Counting = Counting;

fn scalar() -> impl Strategy<Value = Variant> {
    prop_oneof![
        Just(Variant::Empty),
        Just(Variant::Null),
        any::<i16>().prop_map(Variant::I2),
        any::<i32>().prop_map(Variant::I4),
        (-1e30f32..1e30).prop_map(Variant::R4),
        (-1e300f64..1e300).prop_map(Variant::R8),
        any::<i64>().prop_map(Variant::Cy),
        (0.0f64..1e6).prop_map(Variant::Date),
        "\\PC{0,20}".prop_map(Variant::Bstr),
        any::<i32>().prop_map(Variant::Error),
        any::<bool>().prop_map(Variant::Bool),
        any::<u8>().prop_map(Variant::Ui1),
        any::<u16>().prop_map(Variant::Ui2),
        any::<u32>().prop_map(Variant::Ui4),
        any::<i64>().prop_map(Variant::I8),
        any::<u64>().prop_map(Variant::Ui8),
        prop::collection::vec(any::<i16>(), 0..10).prop_map(Variant::I2Array),
        prop::collection::vec(any::<i32>(), 0..10).prop_map(Variant::I4Array),
        prop::collection::vec(-1e30f32..1e30, 0..10).prop_map(Variant::R4Array),
        prop::collection::vec(-1e300f64..1e300, 0..10).prop_map(Variant::R8Array),
        prop::collection::vec("\\PC{0,8}", 0..5).prop_map(Variant::BstrArray),
        prop::collection::vec(any::<bool>(), 0..10).prop_map(Variant::BoolArray),
        prop::collection::vec(any::<u8>(), 0..20).prop_map(Variant::Ui1Array),
    ]
}

fn variant() -> impl Strategy<Value = Variant> {
    scalar().prop_recursive(3, 30, 5, |inner| {
        prop::collection::vec(inner, 0..5).prop_map(Variant::VariantArray)
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn variants_round_trip(v in variant()) {
        let mut b = Vec::new();
        encode_variant(&v, &mut b);
        prop_assert_eq!(decode_variant_exact(&b).unwrap(), v);
    }

    #[test]
    fn packets_round_trip(serial in 1u16.., code in any::<i32>(), args in prop::collection::vec(variant(), 0..6)) {
        let p = Packet { serial, reserved: 0, code, args };
        let bytes = packet_bytes(&p).unwrap();
        prop_assert_eq!(decode_packet(&bytes).unwrap(), p.clone());
        let mut buf = BytesMut::from(&bytes[..]);
        prop_assert_eq!(BcapCodec.decode(&mut buf).unwrap(), Some(p));
    }
}

fn seeds() -> Vec<Vec<u8>> {
    [
        Packet::request(1, func::SERVICE_START, vec![Variant::Bstr(String::new())]),
        Packet::request(
            2,
            func::ROBOT_MOVE,
            vec![
                Variant::I4(2),
                Variant::I4(1),
                Variant::VariantArray(vec![
                    Variant::R8Array(vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]),
                    Variant::Bstr("J".into()),
                    Variant::Bstr("@E".into()),
                ]),
                Variant::Bstr("SPEED=50".into()),
            ],
        ),
        Packet::reply(3, 0, vec![Variant::BstrArray(vec!["Arm".into()])]),
        Packet::reply(
            4,
            0,
            vec![Variant::BoolArray(vec![true]), Variant::I2Array(vec![1])],
        ),
    ]
    .iter()
    .map(|p| packet_bytes(p).unwrap())
    .collect()
}

fn mutate(rng: &mut impl Rng, mut v: Vec<u8>) -> Vec<u8> {
    for _ in 0..rng.random_range(1..4) {
        match rng.random_range(0..5) {
            0 if !v.is_empty() => {
                let i = rng.random_range(0..v.len());
                v[i] ^= 1 << rng.random_range(0..8);
            }
            1 if !v.is_empty() => {
                let n = rng.random_range(0..v.len());
                v.truncate(n);
            }
            2 if v.len() > 8 => {
                // Overwrite a 4-byte field (length / count / arg length) with a random value.
                let i = rng.random_range(0..v.len() - 4);
                let x: u32 = if rng.random() {
                    rng.random()
                } else {
                    rng.random_range(0..64)
                };
                v[i..i + 4].copy_from_slice(&x.to_le_bytes());
            }
            3 => {
                let i = rng.random_range(0..=v.len());
                v.insert(i, rng.random());
            }
            _ => {
                let i = rng.random_range(0..=v.len());
                let n = rng.random_range(0..8);
                let extra: Vec<u8> = (0..n).map(|_| rng.random()).collect();
                v.splice(i..i, extra);
            }
        }
    }
    v
}

#[test]
fn bcap_decoders_survive_100k_random_and_mutated_inputs() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x6243_4150);
    let seeds = seeds();
    let mut worst = 0usize;
    let n = 100_000;
    let mut accepted = 0;
    for i in 0..n {
        let input: Vec<u8> = if i % 2 == 0 {
            let len = rng.random_range(0..300);
            let mut v: Vec<u8> = (0..len).map(|_| rng.random()).collect();
            if !v.is_empty() && rng.random() {
                v[0] = 0x01; // SOH, so the length field gets parsed
            }
            v
        } else {
            let s = seeds[rng.random_range(0..seeds.len())].clone();
            mutate(&mut rng, s)
        };
        MAX_ALLOC.with(|m| m.set(0));
        if decode_packet(&input).is_ok() {
            accepted += 1;
        }
        let _ = decode_variant_exact(&input);
        let mut b = BytesMut::from(&input[..]);
        while let Ok(Some(_)) = BcapCodec.decode(&mut b) {}
        worst = worst.max(MAX_ALLOC.with(|m| m.get()));
    }
    eprintln!(
        "b-CAP: {n} inputs ({accepted} still valid packets), largest single allocation {worst} bytes"
    );
    // Inputs are < 320 bytes: no length or count field may make the decoder allocate ahead
    // of the bytes actually present (the hard cap would be MAX_PACKET = {MAX_PACKET}).
    assert!(
        worst <= 4096,
        "allocation of {worst} bytes (MAX_PACKET {MAX_PACKET})"
    );
}
