//! `serve_all` starts every device of a scenario and reports real, connectable endpoints.

use robocal_mocks::serve::{serve_all, Bind};
use robocal_mocks::{Scenario, WorldHandle};
use std::path::PathBuf;

fn load(name: &str) -> Scenario {
    Scenario::load(
        &PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("scenarios")
            .join(name),
    )
    .unwrap()
}

#[tokio::test]
async fn hospital_scenario_serves_bcap_and_ndi_on_free_ports() {
    let world = WorldHandle::from_scenario(&load("hospital-vs060-vega.toml")).unwrap();
    let served = serve_all(&world, &Bind::default()).await.unwrap();
    let lines = served.json_lines();
    println!("{}", serde_json::to_string(&lines).unwrap());
    let protocols: Vec<&str> = served
        .endpoints
        .iter()
        .map(|e| e.protocol.as_str())
        .collect();
    assert!(protocols.contains(&"ndi-tcp"), "{protocols:?}");
    assert!(served.unavailable.is_empty(), "{:?}", served.unavailable);
    for ep in &served.endpoints {
        let addr = ep.addr.expect("tcp endpoint");
        assert_ne!(addr.port(), 0);
        tokio::net::TcpStream::connect(addr).await.unwrap();
    }
    served.abort();
}

#[tokio::test]
async fn unavailable_protocols_are_reported_not_fatal() {
    // The lab cell's Optotrak has no wire simulator yet: reported, the rest still runs.
    let world = WorldHandle::from_scenario(&load("lab-vs060-optotrak-il600.toml")).unwrap();
    let served = serve_all(&world, &Bind::default()).await.unwrap();
    let lines = served.json_lines();
    println!("{}", serde_json::to_string(&lines).unwrap());
    if served.unavailable.iter().any(|u| u.1 == "optotrak") {
        assert!(lines.iter().any(|l| l["protocol"] == "optotrak"
            && l["error"].as_str().unwrap().contains("not available yet")));
    }
    assert!(served
        .endpoints
        .iter()
        .any(|e| e.protocol == "dl-rs1a" && e.path.is_some()));
    served.abort();
}
