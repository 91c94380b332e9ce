//! RTDE and dashboard decoders: proptest round trips, and ≥ 100,000 random and mutated inputs
//! per decoder that must yield errors, never panics, and never an allocation beyond the
//! protocol's own cap (measured by a counting global allocator).

use bytes::BytesMut;
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use robocal_drivers::ur::dashboard::{parse_robot_mode, parse_safety, LineCodec, MAX_LINE};
use robocal_drivers::ur::rtde::codec::{
    decode_fields, decode_reply, decode_request, encode_fields, encode_reply, encode_request,
    ClientCodec, ServerCodec,
};
use robocal_drivers::ur::rtde::frame::{
    ControllerVersion, DataType, Reply, Request, TextMessage, Value,
};
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

fn reset_max() {
    MAX_ALLOC.with(|m| m.set(0));
}
fn max_alloc() -> usize {
    MAX_ALLOC.with(|m| m.get())
}

fn name() -> impl Strategy<Value = String> {
    "[a-z_]{1,20}[0-9]{0,2}"
}

fn value() -> impl Strategy<Value = Value> {
    prop_oneof![
        any::<bool>().prop_map(Value::Bool),
        any::<u8>().prop_map(Value::Uint8),
        any::<u32>().prop_map(Value::Uint32),
        any::<u64>().prop_map(Value::Uint64),
        any::<i32>().prop_map(Value::Int32),
        any::<f64>()
            .prop_filter("NaN != NaN", |x| !x.is_nan())
            .prop_map(Value::Double),
        prop::array::uniform3(-1e9f64..1e9).prop_map(Value::Vector3d),
        prop::array::uniform6(-1e9f64..1e9).prop_map(Value::Vector6d),
        prop::array::uniform6(any::<i32>()).prop_map(Value::Vector6Int32),
        prop::array::uniform6(any::<u32>()).prop_map(Value::Vector6Uint32),
    ]
}

fn text() -> impl Strategy<Value = TextMessage> {
    ("[ -~]{0,60}", "[ -~]{0,20}", 0u8..4).prop_map(|(message, source, level)| TextMessage {
        message,
        source,
        level,
    })
}

fn request() -> impl Strategy<Value = Request> {
    prop_oneof![
        any::<u16>().prop_map(Request::ProtocolVersion),
        Just(Request::GetControllerVersion),
        text().prop_map(Request::Text),
        (1.0f64..1000.0, prop::collection::vec(name(), 1..10))
            .prop_map(|(frequency, names)| Request::SetupOutputs { frequency, names }),
        prop::collection::vec(name(), 1..10).prop_map(|names| Request::SetupInputs { names }),
        Just(Request::Start),
        Just(Request::Pause),
        (any::<u8>(), prop::collection::vec(any::<u8>(), 0..200))
            .prop_map(|(recipe_id, payload)| Request::Data { recipe_id, payload }),
    ]
}

fn reply() -> impl Strategy<Value = Reply> {
    prop_oneof![
        any::<bool>().prop_map(Reply::ProtocolVersion),
        prop::array::uniform4(any::<u32>()).prop_map(|v| Reply::ControllerVersion(
            ControllerVersion {
                major: v[0],
                minor: v[1],
                bugfix: v[2],
                build: v[3]
            }
        )),
        text().prop_map(Reply::Text),
        (any::<u8>(), prop::collection::vec("[A-Z0-9_]{1,14}", 1..10))
            .prop_map(|(recipe_id, types)| Reply::SetupOutputs { recipe_id, types }),
        (any::<u8>(), prop::collection::vec("[A-Z0-9_]{1,14}", 1..10))
            .prop_map(|(recipe_id, types)| Reply::SetupInputs { recipe_id, types }),
        any::<bool>().prop_map(Reply::Start),
        any::<bool>().prop_map(Reply::Pause),
        (any::<u8>(), prop::collection::vec(any::<u8>(), 0..200))
            .prop_map(|(recipe_id, payload)| Reply::Data { recipe_id, payload }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn requests_round_trip(r in request()) {
        let mut b = BytesMut::new();
        encode_request(&r, &mut b).unwrap();
        let got = ServerCodec.decode(&mut b).unwrap().unwrap();
        prop_assert_eq!(got, r);
        prop_assert!(b.is_empty());
    }

    #[test]
    fn replies_round_trip(r in reply()) {
        let mut b = BytesMut::new();
        encode_reply(&r, &mut b).unwrap();
        let got = ClientCodec.decode(&mut b).unwrap().unwrap();
        prop_assert_eq!(got, r);
    }

    #[test]
    fn fields_round_trip(vals in prop::collection::vec(value(), 0..40)) {
        let mut p = Vec::new();
        encode_fields(&vals, &mut p);
        let types: Vec<DataType> = vals.iter().map(Value::data_type).collect();
        prop_assert_eq!(decode_fields(&types, &p).unwrap(), vals);
    }

    #[test]
    fn lines_round_trip(lines in prop::collection::vec("[ -~]{0,100}", 0..10)) {
        let mut bytes = Vec::new();
        for l in &lines {
            bytes.extend_from_slice(l.as_bytes());
            bytes.push(b'\n');
        }
        prop_assert_eq!(LineCodec::decode_all(&bytes).unwrap(), lines);
    }
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
            2 => {
                let i = rng.random_range(0..=v.len());
                v.insert(i, rng.random());
            }
            3 if v.len() >= 2 => {
                // Rewrite the size field.
                let s: u16 = rng.random();
                v[..2].copy_from_slice(&s.to_be_bytes());
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

fn seeds() -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    let reqs = [
        Request::ProtocolVersion(2),
        Request::GetControllerVersion,
        Request::SetupOutputs {
            frequency: 500.0,
            names: vec!["timestamp".into(), "actual_q".into()],
        },
        Request::SetupInputs {
            names: vec!["input_int_register_0".into()],
        },
        Request::Start,
        Request::Data {
            recipe_id: 1,
            payload: vec![0; 76],
        },
    ];
    for r in &reqs {
        let mut b = BytesMut::new();
        encode_request(r, &mut b).unwrap();
        out.push(b.to_vec());
    }
    let reps = [
        Reply::ProtocolVersion(true),
        Reply::Text(TextMessage {
            message: "hello".into(),
            source: "ctl".into(),
            level: 3,
        }),
        Reply::SetupOutputs {
            recipe_id: 1,
            types: vec!["DOUBLE".into(), "VECTOR6D".into()],
        },
        Reply::Data {
            recipe_id: 1,
            payload: vec![0; 56],
        },
    ];
    for r in &reps {
        let mut b = BytesMut::new();
        encode_reply(r, &mut b).unwrap();
        out.push(b.to_vec());
    }
    out
}

/// Feed `input` to every RTDE decoder; they may fail, never panic.
fn decode_everything(input: &[u8]) {
    let mut b = BytesMut::from(input);
    while let Ok(Some(_)) = ClientCodec.decode(&mut b) {}
    let mut b = BytesMut::from(input);
    while let Ok(Some(_)) = ServerCodec.decode(&mut b) {}
    if let Some((&k, p)) = input.split_first() {
        let _ = decode_reply(k, p);
        let _ = decode_request(k, p);
    }
    let types = [
        DataType::Double,
        DataType::Vector6d,
        DataType::Int32,
        DataType::Uint32,
    ];
    let _ = decode_fields(&types, input);
    let _ = LineCodec::decode_all(input);
    if let Ok(s) = std::str::from_utf8(input) {
        let _ = parse_robot_mode(s);
        let _ = parse_safety(s);
    }
}

#[test]
fn rtde_and_dashboard_decoders_survive_100k_random_and_mutated_inputs() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5254_4445);
    let seeds = seeds();
    let mut worst = 0usize;
    let n = 100_000;
    for i in 0..n {
        let input: Vec<u8> = if i % 2 == 0 {
            let len = rng.random_range(0..300);
            (0..len).map(|_| rng.random()).collect()
        } else {
            let s = seeds[rng.random_range(0..seeds.len())].clone();
            mutate(&mut rng, s)
        };
        reset_max();
        decode_everything(&input);
        worst = worst.max(max_alloc());
    }
    // Inputs are < 320 bytes; no size field may make a decoder allocate ahead of the data
    // (RTDE sizes are u16 and dashboard lines are capped at MAX_LINE anyway).
    let cap = 4096.max(MAX_LINE);
    eprintln!("RTDE/dashboard: {n} inputs, largest single allocation {worst} bytes (cap {cap})");
    assert!(worst <= cap, "allocation of {worst} bytes");
}
