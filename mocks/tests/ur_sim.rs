//! Our UR driver (RTDE + dashboard + script) against the UR simulator over loopback TCP,
//! plus one test per injected fault: the client reports the right `ErrorKind` and recovers
//! where recovery is possible.

use robocal_drivers::ur::dashboard::DashboardClient;
use robocal_drivers::ur::rtde::{RtdeClient, RtdeConfig};
use robocal_drivers::ur::{Backoff, UrArm, UrConfig};
use robocal_drivers::{
    ArmStatus, DeviceError, ErrorKind, FlangePose, JointReadout, MoveJoints, MoveSpeed, SafetyState,
};
use robocal_mocks::serve::{Bind, Endpoint};
use robocal_mocks::world::Fault;
use robocal_mocks::{Scenario, WorldHandle};
use std::net::SocketAddr;
use std::time::Duration;

struct Sim {
    world: WorldHandle,
    eps: Vec<Endpoint>,
}

impl Sim {
    async fn new(clock_real: bool) -> Sim {
        let mut s = Scenario::single_arm("ur5e", 7);
        if clock_real {
            s.clock = robocal_mocks::scenario::ClockMode::Real;
        }
        let world = WorldHandle::from_scenario(&s).unwrap();
        let eps = robocal_mocks::ur::start(world.clone(), "arm", &Bind::default())
            .await
            .unwrap();
        Sim { world, eps }
    }
    fn addr(&self, proto: &str) -> SocketAddr {
        self.eps
            .iter()
            .find(|e| e.protocol == proto)
            .and_then(|e| e.addr)
            .unwrap()
    }
    fn config(&self) -> UrConfig {
        let mut c = UrConfig::new("127.0.0.1");
        c.name = "ur5e-sim".into();
        c.rtde_port = self.addr("rtde").port();
        c.dashboard_port = self.addr("dashboard").port();
        c.script_port = self.addr("script").port();
        c.rtde.stream_timeout = Duration::from_millis(500);
        c.request_timeout = Duration::from_millis(800);
        c.start_timeout = Duration::from_millis(1000);
        c.backoff = Backoff {
            attempts: 4,
            initial: Duration::from_millis(20),
            max: Duration::from_millis(100),
        };
        c
    }
    async fn arm(&self) -> UrArm {
        UrArm::connect(self.config()).await.unwrap()
    }
    fn rtde_cfg() -> RtdeConfig {
        RtdeConfig {
            stream_timeout: Duration::from_millis(500),
            request_timeout: Duration::from_millis(800),
            ..RtdeConfig::default()
        }
    }
}

impl Drop for Sim {
    fn drop(&mut self) {
        for e in &self.eps {
            e.abort();
        }
    }
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn handshake_readout_and_flange_match_the_world() {
    let sim = Sim::new(false).await;
    let rtde = RtdeClient::connect(&sim.addr("rtde").to_string(), Sim::rtde_cfg())
        .await
        .unwrap();
    assert_eq!(rtde.version().major, 5);
    assert_eq!(rtde.version().minor, 11);
    let s1 = rtde.next_sample().await.unwrap();
    let s2 = rtde.next_sample().await.unwrap();
    assert!(s2.seq > s1.seq);

    let arm = sim.arm().await;
    let js = arm.joints().await.unwrap();
    let truth = sim.world.arm_joint_state(0);
    assert!(
        max_diff(&js.q, &truth.q) < 1e-12,
        "{:?} vs {:?}",
        js.q,
        truth.q
    );
    let f = arm.flange_pose().await.unwrap().0;
    let w = sim.world.arm_controller_flange(0);
    assert!((f.translation.vector - w.translation.vector).norm() < 1e-9);
    assert!(f.rotation.angle_to(&w.rotation) < 1e-9);
    let st = arm.state().await.unwrap();
    assert_eq!(st.safety, SafetyState::Normal);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn movej_reaches_the_target_in_virtual_and_real_time() {
    for real in [false, true] {
        let sim = Sim::new(real).await;
        let arm = sim.arm().await;
        let target = [0.2, -1.2, 0.9, -0.4, 0.3, 0.1];
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
        let q = sim.world.arm_joint_state(0).q;
        assert!(max_diff(&q, &target) < 1e-3, "real={real}: {q:?}");
        assert!(
            !sim.world.arm_is_moving(0),
            "real={real}: reported arrival while moving"
        );
        // Simulated time passed at least the trapezoid duration of the 1.2 rad joint-2 move.
        let dt = sim.world.now() - t0;
        assert!(dt >= 0.7, "real={real}: move took {dt} s of world time");
        let js = arm.joints().await.unwrap();
        assert!(max_diff(&js.q, &q) < 1e-3);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dashboard_power_cycle_and_not_ready_is_device_rejected() {
    let sim = Sim::new(false).await;
    let arm = sim.arm().await;
    let d = arm.dashboard().await.unwrap();
    assert!(d.banner().contains("Dashboard"));
    d.power_off().await.unwrap();
    let e = arm
        .move_joints(&[0.1; 6], MoveSpeed::default())
        .await
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::DeviceRejected, "{e}");
    arm.power_up().await.unwrap();
    arm.move_joints(&[0.1; 6], MoveSpeed::default())
        .await
        .unwrap();
    // play without a loaded program is refused; load + play accepted; stop accepted.
    let e = d.play().await.unwrap_err();
    assert_eq!(e.kind(), ErrorKind::DeviceRejected);
    assert!(d
        .command("load cal.urp")
        .await
        .unwrap()
        .starts_with("Loading program"));
    d.play().await.unwrap();
    d.stop().await.unwrap();
    assert_eq!(
        d.command("frobnicate").await.unwrap(),
        "could not understand: 'frobnicate'"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn out_of_limit_target_is_device_rejected_and_arm_stays() {
    let sim = Sim::new(false).await;
    let arm = sim.arm().await;
    let before = sim.world.arm_joint_state(0).q;
    let e = arm
        .move_joints(&[0.0, 0.0, 100.0, 0.0, 0.0, 0.0], MoveSpeed::default())
        .await
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::DeviceRejected, "{e}");
    assert!(max_diff(&before, &sim.world.arm_joint_state(0).q) < 1e-12);
    // Still usable.
    arm.move_joints(&[0.05; 6], MoveSpeed::default())
        .await
        .unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn protective_stop_is_safety_stop_and_recovers_through_dashboard() {
    let sim = Sim::new(false).await;
    let arm = sim.arm().await;
    sim.world.control().protective_stop(0);
    let e = arm
        .move_joints(&[0.3; 6], MoveSpeed::default())
        .await
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::SafetyStop, "{e}");
    assert_eq!(
        arm.state().await.unwrap().safety,
        SafetyState::ProtectiveStop
    );
    arm.recover().await.unwrap();
    assert_eq!(arm.state().await.unwrap().safety, SafetyState::Normal);
    arm.move_joints(&[0.3; 6], MoveSpeed::default())
        .await
        .unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn protective_stop_during_a_real_time_move_aborts_it() {
    let sim = Sim::new(true).await;
    let arm = std::sync::Arc::new(sim.arm().await);
    let a2 = arm.clone();
    let mv = tokio::spawn(async move {
        a2.move_joints(
            &[1.0, -1.0, 1.0, 0.0, 0.0, 0.0],
            MoveSpeed {
                max_vel: 0.5,
                max_acc: 2.0,
            },
        )
        .await
    });
    while !sim.world.arm_is_moving(0) {
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    sim.world.control().protective_stop(0);
    let e = mv.await.unwrap().unwrap_err();
    assert_eq!(e.kind(), ErrorKind::SafetyStop, "{e}");
}

// ------------------------------------------------------------------ wire faults (RTDE)

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtde_drop_link_is_disconnected_and_arm_reconnects() {
    let sim = Sim::new(false).await;
    let raw = RtdeClient::connect(&sim.addr("rtde").to_string(), Sim::rtde_cfg())
        .await
        .unwrap();
    raw.next_sample().await.unwrap();
    sim.world.control().inject("arm", Fault::DropLink);
    let e = loop {
        match raw.next_sample().await {
            Ok(_) => continue,
            Err(e) => break e,
        }
    };
    assert_eq!(e.kind(), ErrorKind::Disconnected, "{e}");

    let arm = sim.arm().await;
    arm.joints().await.unwrap();
    sim.world.control().inject("arm", Fault::DropLink);
    // The arm reconnects with backoff and answers.
    for _ in 0..5 {
        arm.sample(true).await.unwrap();
    }
    assert_eq!(sim.world.control().pending_faults("arm"), 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtde_truncated_frame_is_disconnected() {
    let sim = Sim::new(false).await;
    let raw = RtdeClient::connect(&sim.addr("rtde").to_string(), Sim::rtde_cfg())
        .await
        .unwrap();
    sim.world.control().inject("arm", Fault::Truncated);
    let e = loop {
        if let Err(e) = raw.next_sample().await {
            break e;
        }
    };
    assert_eq!(e.kind(), ErrorKind::Disconnected, "{e}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtde_garbage_and_bad_size_are_protocol_then_recover() {
    for fault in [
        Fault::Garbage {
            bytes: vec![0x00, 0x05, b'Z', 1, 2],
        },
        Fault::BadCrc,
    ] {
        let sim = Sim::new(false).await;
        let raw = RtdeClient::connect(&sim.addr("rtde").to_string(), Sim::rtde_cfg())
            .await
            .unwrap();
        sim.world.control().inject("arm", fault.clone());
        let e = loop {
            if let Err(e) = raw.next_sample().await {
                break e;
            }
        };
        assert_eq!(e.kind(), ErrorKind::Protocol, "{fault:?}: {e}");
        assert!(raw.is_closed());
        // The arm drops the poisoned session and reconnects (at the latest on the next call):
        // a call either succeeds or reports Protocol, never anything else.
        let arm = sim.arm().await;
        sim.world.control().inject("arm", fault.clone());
        for _ in 0..50 {
            if let Err(e) = arm.sample(true).await {
                assert_eq!(e.kind(), ErrorKind::Protocol, "{e}");
            }
        }
        assert_eq!(sim.world.control().pending_faults("arm"), 0);
        arm.joints().await.unwrap();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtde_silence_is_timeout_and_arm_recovers() {
    let sim = Sim::new(false).await;
    let raw = RtdeClient::connect(&sim.addr("rtde").to_string(), Sim::rtde_cfg())
        .await
        .unwrap();
    sim.world
        .control()
        .inject("arm", Fault::Silence { secs: 1.5 });
    let e = loop {
        if let Err(e) = raw.next_sample().await {
            break e;
        }
    };
    assert_eq!(e.kind(), ErrorKind::Timeout, "{e}");
    let arm = sim.arm().await;
    arm.joints().await.unwrap();
    sim.world
        .control()
        .inject("arm", Fault::Delay { secs: 1.5 });
    // A silent stream makes the arm reconnect; the call still succeeds on the new session.
    for _ in 0..5 {
        arm.sample(true).await.unwrap();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtde_refused_handshake_is_device_rejected() {
    let sim = Sim::new(false).await;
    sim.world
        .control()
        .inject("arm", Fault::ErrorReply { code: 1 });
    let e = RtdeClient::connect(&sim.addr("rtde").to_string(), Sim::rtde_cfg())
        .await
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::DeviceRejected, "{e}");
    // Unknown variables are the controller saying no, too.
    let cfg = RtdeConfig {
        outputs: vec!["actual_q".into(), "no_such_variable".into()],
        ..Sim::rtde_cfg()
    };
    let e = RtdeClient::connect(&sim.addr("rtde").to_string(), cfg)
        .await
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::DeviceRejected, "{e}");
    RtdeClient::connect(&sim.addr("rtde").to_string(), Sim::rtde_cfg())
        .await
        .unwrap();
}

// ------------------------------------------------------------- wire faults (dashboard, script)

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dashboard_faults_map_to_kinds_and_recover() {
    let sim = Sim::new(false).await;
    let addr = sim.addr("dashboard").to_string();
    let t = Duration::from_millis(500);
    let d = DashboardClient::connect(&addr, t).await.unwrap();
    let q = "arm/dashboard";
    sim.world.control().inject(q, Fault::Delay { secs: 1.2 });
    assert_eq!(d.robot_mode().await.unwrap_err().kind(), ErrorKind::Timeout);

    let d = DashboardClient::connect(&addr, t).await.unwrap();
    sim.world.control().inject(q, Fault::DropLink);
    assert_eq!(
        d.robot_mode().await.unwrap_err().kind(),
        ErrorKind::Disconnected
    );

    let d = DashboardClient::connect(&addr, t).await.unwrap();
    sim.world.control().inject(q, Fault::Truncated);
    assert_eq!(
        d.robot_mode().await.unwrap_err().kind(),
        ErrorKind::Disconnected
    );

    let d = DashboardClient::connect(&addr, t).await.unwrap();
    sim.world.control().inject(
        q,
        Fault::Garbage {
            bytes: b"\xff\xfe\n".to_vec(),
        },
    );
    assert_eq!(
        d.robot_mode().await.unwrap_err().kind(),
        ErrorKind::Protocol
    );

    let d = DashboardClient::connect(&addr, t).await.unwrap();
    sim.world.control().inject(q, Fault::BadCrc); // a mangled (lower-cased) reply line
    assert_eq!(
        d.robot_mode().await.unwrap_err().kind(),
        ErrorKind::Protocol
    );
    assert_eq!(
        d.robot_mode().await.unwrap(),
        robocal_drivers::ur::rtde::RobotMode::Running
    );

    let d = DashboardClient::connect(&addr, t).await.unwrap();
    sim.world.control().inject(q, Fault::ErrorReply { code: 0 });
    assert_eq!(
        d.power_on().await.unwrap_err().kind(),
        ErrorKind::DeviceRejected
    );
    d.power_on().await.unwrap();

    // Through the arm: a dropped dashboard link is reconnected inside the same call.
    let arm = sim.arm().await;
    sim.world.control().inject(q, Fault::DropLink);
    arm.recover().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn script_link_drop_is_reported_then_recovers() {
    let sim = Sim::new(false).await;
    let arm = sim.arm().await;
    sim.world.control().inject("arm/script", Fault::DropLink);
    let e = arm
        .move_joints(&[0.2; 6], MoveSpeed::default())
        .await
        .unwrap_err();
    assert_eq!(e.kind(), ErrorKind::DeviceRejected, "{e}");
    // The script client reconnects on the broken pipe; the next move works.
    let mut last = None;
    for _ in 0..3 {
        match arm.move_joints(&[0.2; 6], MoveSpeed::default()).await {
            Ok(()) => {
                last = None;
                break;
            }
            Err(e) => last = Some(e),
        }
    }
    assert!(last.is_none(), "{last:?}");
    assert!(max_diff(&sim.world.arm_joint_state(0).q, &[0.2; 6]) < 1e-3);
}

#[test]
fn driver_errors_keep_their_kind() {
    use robocal_drivers::ur::UrError;
    let e = UrError::MoveAborted { detail: "x".into() };
    assert_eq!(e.kind(), ErrorKind::DeviceRejected);
}
