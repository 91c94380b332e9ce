//! b-CAP: literal bytes from the protocol brief against the simulator, our `DensoArm` against
//! the simulator, and one test per injected fault (kind + recovery).
//!
//! No public b-CAP client installs from PyPI (`pip download bcapclient` / `pybcapclient`: no
//! distribution), so the wire check uses the brief's byte sequences, which were produced by
//! the packing rules of DENSO's own Python client (orin_bcap `Python/bCAPClient/bcapclient.py`).

use robocal_drivers::bcap::frame::{func, hresult, Packet, Variant};
use robocal_drivers::bcap::{BcapClient, BcapError, DensoArm, DensoConfig};
use robocal_drivers::ur::Backoff;
use robocal_drivers::{
    ArmMode, ArmStatus, DeviceError, ErrorKind, FlangePose, JointReadout, MoveJoints, MoveSpeed,
    SafetyState,
};
use robocal_mocks::serve::{Bind, Endpoint};
use robocal_mocks::world::Fault;
use robocal_mocks::{Scenario, WorldHandle};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

struct Sim {
    world: WorldHandle,
    eps: Vec<Endpoint>,
}

impl Sim {
    async fn new(real: bool) -> Sim {
        let mut s = Scenario::single_arm("denso-vs060", 5);
        if real {
            s.clock = robocal_mocks::scenario::ClockMode::Real;
        }
        let world = WorldHandle::from_scenario(&s).unwrap();
        let eps = robocal_mocks::bcap::start(world.clone(), "arm", &Bind::default())
            .await
            .unwrap();
        Sim { world, eps }
    }
    fn addr(&self) -> String {
        self.eps[0].addr.unwrap().to_string()
    }
    fn config(&self) -> DensoConfig {
        let mut c = DensoConfig::new(self.addr());
        c.name = "vs060-sim".into();
        c.timeout = Duration::from_millis(700);
        c.backoff = Backoff {
            attempts: 4,
            initial: Duration::from_millis(20),
            max: Duration::from_millis(100),
        };
        c
    }
    async fn arm(&self) -> DensoArm {
        DensoArm::connect(self.config()).await.unwrap()
    }
    async fn client(&self) -> BcapClient {
        BcapClient::connect(&self.addr(), Duration::from_millis(700))
            .await
            .unwrap()
    }
}

impl Drop for Sim {
    fn drop(&mut self) {
        for e in &self.eps {
            e.abort();
        }
    }
}

fn hex(s: &str) -> Vec<u8> {
    let s: String = s.split_whitespace().collect();
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn brief_byte_sequences_get_the_brief_replies() {
    let sim = Sim::new(false).await;
    let mut s = tokio::net::TcpStream::connect(sim.addr()).await.unwrap();
    // Service_Start(""), serial 1 — brief §2.2.
    s.write_all(&hex(
        "01 1e000000 0100 0000 01000000 0100 0a000000 0800 01000000 00000000 04",
    ))
    .await
    .unwrap();
    let mut r = [0u8; 16];
    s.read_exact(&mut r).await.unwrap();
    assert_eq!(r.to_vec(), hex("01 10000000 0100 0000 00000000 0000 04"));
    // Controller_Connect("", "CaoProv.DENSO.VRC", "localhost", ""), serial 2, built with the
    // same packing rules; the first handle comes back as VT_I4 1 — the brief's 30-byte reply.
    let req = robocal_drivers::bcap::codec::packet_bytes(&Packet::request(
        2,
        func::CONTROLLER_CONNECT,
        vec![
            Variant::Bstr(String::new()),
            Variant::Bstr("CaoProv.DENSO.VRC".into()),
            Variant::Bstr("localhost".into()),
            Variant::Bstr(String::new()),
        ],
    ))
    .unwrap();
    s.write_all(&req).await.unwrap();
    let mut r = [0u8; 30];
    s.read_exact(&mut r).await.unwrap();
    assert_eq!(
        r.to_vec(),
        hex("01 1e000000 0200 0000 00000000 0100 0a000000 0300 01000000 01000000 04")
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn arm_reads_and_moves_like_the_world() {
    for real in [false, true] {
        let sim = Sim::new(real).await;
        let arm = sim.arm().await;
        let js = arm.joints().await.unwrap();
        assert!(max_diff(&js.q, &sim.world.arm_joint_state(0).q) < 1e-12);
        let f = arm.flange_pose().await.unwrap().0;
        let w = sim.world.arm_controller_flange(0);
        assert!((f.translation.vector - w.translation.vector).norm() < 1e-9);
        assert!(f.rotation.angle_to(&w.rotation) < 1e-9);
        let target = [0.3, 0.2, 1.4, -0.2, 0.5, 0.1];
        let t0 = sim.world.now();
        arm.move_joints(
            &target,
            MoveSpeed {
                max_vel: 2.0,
                max_acc: 8.0,
            },
        )
        .await
        .unwrap();
        assert!(!sim.world.arm_is_moving(0), "real={real}");
        let q = sim.world.arm_joint_state(0).q;
        assert!(max_diff(&q, &target) < 1e-3, "real={real}: {q:?}");
        assert!(sim.world.now() - t0 > 0.5, "real={real}");
        let st = arm.state().await.unwrap();
        assert_eq!(st.mode, ArmMode::Ready);
        assert_eq!(st.safety, SafetyState::Normal);
        arm.close().await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hresults_are_device_rejected() {
    let sim = Sim::new(false).await;
    let c = sim.client().await;
    c.service_start("").await.unwrap();
    let h = c
        .controller_connect("", "CaoProv.DENSO.VRC", "localhost", "")
        .await
        .unwrap();
    let r = c.controller_get_robot(h, "Arm").await.unwrap();
    let code = |e: BcapError| {
        assert_eq!(e.kind(), ErrorKind::DeviceRejected, "{e}");
        e.hresult().unwrap()
    };
    assert_eq!(
        code(
            c.robot_execute(999, "CurJnt", Variant::Empty)
                .await
                .unwrap_err()
        ),
        hresult::E_HANDLE
    );
    assert_eq!(
        code(
            c.robot_execute(r, "Dance", Variant::Empty)
                .await
                .unwrap_err()
        ),
        hresult::E_INVALID_CMD_NAME
    );
    assert_eq!(
        code(
            c.robot_execute(r, "Motor", Variant::I4Array(vec![1, 0]))
                .await
                .unwrap_err()
        ),
        hresult::E_ACCESSDENIED
    );
    c.robot_execute(r, "TakeArm", Variant::I4Array(vec![0, 0]))
        .await
        .unwrap();
    let mv = |deg: &str| c.robot_move(r, 1, Variant::Bstr(deg.into()), "", Duration::from_secs(5));
    assert_eq!(
        code(mv("@E J(0,0,0,0,0,0)").await.unwrap_err()),
        hresult::E_SIM_MOTOR_OFF
    );
    c.robot_execute(r, "Motor", Variant::I4Array(vec![1, 0]))
        .await
        .unwrap();
    assert_eq!(
        code(mv("@E J(0,0,500,0,0,0)").await.unwrap_err()),
        hresult::E_SIM_OUT_OF_RANGE
    );
    assert_eq!(
        code(mv("@P P(300,0,400,180,0,180,-1)").await.unwrap_err()),
        hresult::E_NOTIMPL
    );
    assert_eq!(
        code(c.controller_get_variable(h, "@NOPE").await.unwrap_err()),
        hresult::E_CAO_OBJECT_NOTFOUND
    );
    // The VARIANT-array pose form moves too.
    c.robot_move(
        r,
        1,
        Variant::VariantArray(vec![
            Variant::R8Array(vec![5.0, 5.0, 95.0, 0.0, 5.0, 0.0]),
            Variant::Bstr("J".into()),
            Variant::Bstr("@E".into()),
        ]),
        "SPEED=50",
        Duration::from_secs(5),
    )
    .await
    .unwrap();
    let deg = c
        .robot_execute(r, "CurJnt", Variant::Empty)
        .await
        .unwrap()
        .as_f64_vec()
        .unwrap();
    assert!(
        max_diff(&deg, &[5.0, 5.0, 95.0, 0.0, 5.0, 0.0]) < 0.06,
        "{deg:?}"
    );
    c.service_stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn s_executing_keepalives_carry_a_long_move_past_the_reply_deadline() {
    let sim = Sim::new(true).await;
    let c = sim.client().await;
    c.service_start(",WDT=100,InvokeTimeout=180000")
        .await
        .unwrap();
    let h = c
        .controller_connect("", "CaoProv.DENSO.VRC", "localhost", "")
        .await
        .unwrap();
    let r = c.controller_get_robot(h, "Arm").await.unwrap();
    c.robot_execute(r, "TakeArm", Variant::I4Array(vec![0, 0]))
        .await
        .unwrap();
    c.robot_execute(r, "Motor", Variant::I4Array(vec![1, 0]))
        .await
        .unwrap();
    let t0 = std::time::Instant::now();
    // ~1.2 s move, 300 ms reply deadline: only the S_EXECUTING keepalives keep the call alive.
    c.call_with(
        func::ROBOT_MOVE,
        vec![
            Variant::I4(r),
            Variant::I4(1),
            Variant::Bstr("@E J(60,0,90,0,0,0)".into()),
            Variant::Bstr("SPEED=40,ACCEL=100,DECEL=100".into()),
        ],
        Duration::from_millis(300),
        Duration::from_secs(10),
    )
    .await
    .unwrap();
    assert!(
        t0.elapsed() > Duration::from_millis(600),
        "{:?}",
        t0.elapsed()
    );
    // Without WDT the same deadline expires: Timeout.
    let c2 = sim.client().await;
    c2.service_start("").await.unwrap();
    let h2 = c2
        .controller_connect("", "CaoProv.DENSO.VRC", "localhost", "")
        .await
        .unwrap();
    let r2 = c2.controller_get_robot(h2, "Arm").await.unwrap();
    c.robot_execute(r, "GiveArm", Variant::Empty).await.unwrap();
    c2.robot_execute(r2, "TakeArm", Variant::I4Array(vec![0, 0]))
        .await
        .unwrap();
    c2.robot_execute(r2, "Motor", Variant::I4Array(vec![1, 0]))
        .await
        .unwrap();
    let e = c2
        .call_with(
            func::ROBOT_MOVE,
            vec![
                Variant::I4(r2),
                Variant::I4(1),
                Variant::Bstr("@E J(0,0,90,0,0,0)".into()),
                Variant::Bstr("SPEED=40,ACCEL=100,DECEL=100".into()),
            ],
            Duration::from_millis(300),
            Duration::from_secs(10),
        )
        .await
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::Timeout, "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_request_during_a_move_gets_e_busy_proc() {
    use futures_util::{SinkExt, StreamExt};
    let sim = Sim::new(true).await;
    let s = tokio::net::TcpStream::connect(sim.addr()).await.unwrap();
    let mut f = tokio_util::codec::Framed::new(s, robocal_drivers::bcap::codec::BcapCodec);
    let call = Packet::request;
    let seq = [
        call(1, func::SERVICE_START, vec![Variant::Bstr(String::new())]),
        call(
            2,
            func::CONTROLLER_CONNECT,
            vec![Variant::Bstr(String::new()); 4],
        ),
        call(
            3,
            func::CONTROLLER_GET_ROBOT,
            vec![
                Variant::I4(1),
                Variant::Bstr("Arm".into()),
                Variant::Bstr(String::new()),
            ],
        ),
        call(
            4,
            func::ROBOT_EXECUTE,
            vec![
                Variant::I4(2),
                Variant::Bstr("TakeArm".into()),
                Variant::I4Array(vec![0, 0]),
            ],
        ),
        call(
            5,
            func::ROBOT_EXECUTE,
            vec![
                Variant::I4(2),
                Variant::Bstr("Motor".into()),
                Variant::I4Array(vec![1, 0]),
            ],
        ),
    ];
    for p in seq {
        let serial = p.serial;
        f.send(p).await.unwrap();
        let r = f.next().await.unwrap().unwrap();
        assert_eq!((r.serial, r.code), (serial, hresult::S_OK));
    }
    f.send(Packet::request(
        6,
        func::ROBOT_MOVE,
        vec![
            Variant::I4(2),
            Variant::I4(1),
            Variant::Bstr("J(30,0,90,0,0,0)".into()),
            Variant::Bstr("SPEED=50".into()),
        ],
    ))
    .await
    .unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    f.send(Packet::request(
        7,
        func::ROBOT_EXECUTE,
        vec![
            Variant::I4(2),
            Variant::Bstr("CurJnt".into()),
            Variant::Empty,
        ],
    ))
    .await
    .unwrap();
    let r = f.next().await.unwrap().unwrap();
    assert_eq!((r.serial, r.code), (7, hresult::E_BUSY_PROC));
    let r = f.next().await.unwrap().unwrap();
    assert_eq!((r.serial, r.code), (6, hresult::S_OK));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn protective_stop_is_safety_stop_and_clear_error_recovers() {
    let sim = Sim::new(false).await;
    let arm = sim.arm().await;
    arm.move_joints(&[0.1, 0.1, 1.5, 0.0, 0.1, 0.0], MoveSpeed::default())
        .await
        .unwrap();
    sim.world.control().protective_stop(0);
    let e = arm
        .move_joints(&[0.2, 0.1, 1.5, 0.0, 0.1, 0.0], MoveSpeed::default())
        .await
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::SafetyStop, "{e}");
    assert_eq!(
        arm.state().await.unwrap().safety,
        SafetyState::ProtectiveStop
    );
    arm.recover().await.unwrap();
    assert_eq!(arm.state().await.unwrap().safety, SafetyState::Normal);
    arm.move_joints(&[0.2, 0.1, 1.5, 0.0, 0.1, 0.0], MoveSpeed::default())
        .await
        .unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn wire_faults_map_to_kinds_and_the_arm_recovers() {
    let sim = Sim::new(false).await;
    let arm = sim.arm().await;
    arm.joints().await.unwrap();
    let cases: Vec<(Fault, ErrorKind)> = vec![
        (Fault::DropLink, ErrorKind::Disconnected),
        (Fault::Truncated, ErrorKind::Disconnected),
        (Fault::Delay { secs: 1.4 }, ErrorKind::Timeout),
        (Fault::Silence { secs: 1.4 }, ErrorKind::Timeout),
        (
            Fault::Garbage {
                bytes: vec![0x55; 20],
            },
            ErrorKind::Protocol,
        ),
        (Fault::BadCrc, ErrorKind::Protocol),
        (
            Fault::ErrorReply {
                code: hresult::E_FAIL as i64,
            },
            ErrorKind::DeviceRejected,
        ),
    ];
    for (fault, kind) in cases {
        // Raw client: the fault's kind.
        let c = sim.client().await;
        c.service_start("").await.unwrap();
        sim.world.control().inject("arm", fault.clone());
        let e = c.service_start("").await.unwrap_err();
        assert_eq!(e.kind(), kind, "{fault:?}: {e}");
        // Through the arm: a link failure is retried on a new session inside the call; a
        // protocol error poisons the session, which the next call rebuilds; a refusal is final.
        sim.world.control().inject("arm", fault.clone());
        match arm.joints().await {
            Ok(js) => assert!(
                kind.needs_reconnect(),
                "{fault:?} should have failed, got {js:?}"
            ),
            Err(e) => assert_eq!(e.kind(), kind, "{fault:?}: {e}"),
        }
        let js = arm.joints().await.unwrap();
        assert!(max_diff(&js.q, &sim.world.arm_joint_state(0).q) < 1e-12);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn drop_gives_the_arm_back() {
    let sim = Sim::new(false).await;
    let a = sim.arm().await;
    a.move_joints(&[0.0, 0.0, 1.5, 0.0, 0.0, 0.0], MoveSpeed::default())
        .await
        .unwrap();
    // Another session holding the arm for longer than `take_arm_wait`: refused, named.
    let mut impatient = sim.config();
    impatient.take_arm_wait = Duration::from_millis(200);
    let b = DensoArm::connect(impatient).await.unwrap();
    let t0 = std::time::Instant::now();
    let e = b
        .move_joints(&[0.1, 0.0, 1.5, 0.0, 0.0, 0.0], MoveSpeed::default())
        .await
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::DeviceRejected, "{e}");
    assert!(e.to_string().contains("E_ACCESSDENIED"), "{e}");
    assert!(
        t0.elapsed() >= Duration::from_millis(150),
        "{:?}",
        t0.elapsed()
    );
    // A session whose holder goes away while it waits (a dead connection of our own after a
    // dropped link) gets the arm as soon as the controller releases it: no failed move.
    let mut patient = sim.config();
    patient.take_arm_wait = Duration::from_secs(5);
    let c = DensoArm::connect(patient).await.unwrap();
    let dropper = tokio::spawn(async move {
        tokio::time::sleep(Duration::from_millis(300)).await;
        drop(a);
    });
    let t0 = std::time::Instant::now();
    c.move_joints(&[0.1, 0.0, 1.5, 0.0, 0.0, 0.0], MoveSpeed::default())
        .await
        .expect("the move waits for the release");
    assert!(
        t0.elapsed() >= Duration::from_millis(250),
        "{:?}",
        t0.elapsed()
    );
    dropper.await.unwrap();
    drop(b);
}
