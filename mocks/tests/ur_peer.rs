//! The public Python package `ur-rtde` (PyPI 1.6.5, venv `.venv/peers-urrtde`, installed by
//! `.ci/peers.sh`) against the UR simulator. ur_rtde connects to the vendor's fixed ports, so
//! every test binds its simulator to its own loopback address 127.x.y.1.
//!
//! Without the venv these tests print a loud SKIP, unless `CI` is set (then they fail).

use robocal_mocks::serve::Bind;
use robocal_mocks::{Scenario, WorldHandle};
use std::net::{IpAddr, Ipv4Addr};
use std::path::PathBuf;
use std::time::Duration;

mod peer;

/// A loopback address unique to this process and test (ur_rtde needs the fixed ports).
fn host(test: u8) -> IpAddr {
    let pid = std::process::id();
    IpAddr::V4(Ipv4Addr::new(
        127,
        100 + (pid % 150) as u8,
        (pid / 150 % 250) as u8,
        10 + test,
    ))
}

async fn run_peer(args: Vec<String>) -> serde_json::Value {
    let py = python().expect("checked by caller");
    let (script, rest) = args.split_first().expect("script path first");
    let script = PathBuf::from(script);
    let name = script.file_name().unwrap().to_string_lossy().into_owned();
    let lines = peer::run_json_lines(&py, &name, rest.to_vec(), Duration::from_secs(60)).await;
    lines.into_iter().last().expect("no JSON from peer")
}

fn python() -> Option<PathBuf> {
    peer::python("urrtde", "ur-rtde peer test")
}

fn start_world(home_deg: Vec<f64>) -> WorldHandle {
    let mut s = Scenario::single_arm("ur5e", 11);
    s.arms[0].home_deg = Some(home_deg);
    WorldHandle::from_scenario(&s).unwrap()
}

fn floats(v: &serde_json::Value) -> Vec<f64> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ur_rtde_receive_reads_the_world_joints() {
    if python().is_none() {
        return;
    }
    let world = start_world(vec![10.0, -80.0, 70.0, -30.0, 45.0, 5.0]);
    let bind = Bind {
        host: host(1),
        standard_ports: true,
    };
    let eps = robocal_mocks::ur::start(world.clone(), "arm", &bind)
        .await
        .unwrap();
    let script = peer::workspace().join("scripts/peers/ur_rtde_receive.py");
    let j = run_peer(vec![script.display().to_string(), bind.host.to_string()]).await;
    eprintln!("ur_rtde receive peer: {j}");
    let q = floats(&j["actual_q"]);
    let truth = world.arm_joint_state(0).q;
    for (a, b) in q.iter().zip(&truth) {
        assert!(
            (a - b).abs() < 1e-12,
            "ur_rtde getActualQ {q:?} vs world {truth:?}"
        );
    }
    let tcp = floats(&j["actual_tcp_pose"]);
    let f = world.arm_controller_flange(0);
    assert!((tcp[0] * 1000.0 - f.translation.x).abs() < 1e-9);
    assert!((tcp[2] * 1000.0 - f.translation.z).abs() < 1e-9);
    assert_eq!(j["robot_mode"], 7);
    assert_eq!(j["safety_mode"], 1);
    assert_eq!(j["runtime_state"], 1);
    assert_eq!(j["dashboard_connected"], true);
    assert_eq!(j["robotmode"], "Robotmode: RUNNING");
    assert_eq!(j["remote"], true);
    assert!(j["serial"].as_str().unwrap().starts_with("20"));
    for e in &eps {
        e.abort();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ur_rtde_control_movej_moves_the_simulated_arm() {
    if python().is_none() {
        return;
    }
    let world = start_world(vec![0.0, -90.0, 90.0, -90.0, -90.0, 0.0]);
    let bind = Bind {
        host: host(2),
        standard_ports: true,
    };
    let eps = robocal_mocks::ur::start(world.clone(), "arm", &bind)
        .await
        .unwrap();
    let target = [0.3, -1.3, 1.2, -1.4, -1.5, 0.4];
    let t0 = world.now();
    let mut args = vec![
        peer::workspace()
            .join("scripts/peers/ur_rtde_control.py")
            .display()
            .to_string(),
        bind.host.to_string(),
    ];
    args.extend(target.iter().map(|x| x.to_string()));
    let j = run_peer(args).await;
    eprintln!("ur_rtde control peer: {j}");
    assert_eq!(j["control_connected"], true, "{j}");
    assert_eq!(j["movej"], true, "{j}");
    let q = world.arm_joint_state(0).q;
    for (a, b) in q.iter().zip(&target) {
        assert!(
            (a - b).abs() < 1e-3,
            "world joints {q:?} vs moveJ target {target:?}"
        );
    }
    let peer_q = floats(&j["actual_q"]);
    for (a, b) in peer_q.iter().zip(&q) {
        assert!((a - b).abs() < 1e-9, "peer read {peer_q:?}, world {q:?}");
    }
    assert!(world.now() - t0 > 0.5, "the move took no simulated time");
    for e in &eps {
        e.abort();
    }
}
