//! Issue 30 §1 / seed 004: a camera session that starts with the operator's four hand-guided
//! poses (`session --teach-board 4`): the simulated operator drags the DENSO (its teach
//! pendant holds it; robocal only reads the joints) through four poses where the camera sees
//! the board; their images alone (intrinsics, Tsai–Lenz hand-eye) locate the board in the base
//! and the shell of viewpoints is centred on it.

use crate::common::{bin as run, root, s as p};

#[test]
fn teach_board_locates_the_board_from_four_hand_guided_views() {
    let tmp = tempfile::tempdir().unwrap();
    let scen = root().join("mocks/scenarios/vs060-camera.toml");
    // Four viewpoints the operator might choose: spread over the session's own shell plan.
    let first = tmp.path().join("first");
    let (code, _, stderr) = run(&[
        "session",
        "--sim",
        p(&scen),
        "--plan-only",
        "--out",
        p(&first),
        "--no-history",
    ]);
    assert_eq!(code, Some(0), "{stderr}");
    let plan = robocal::plan::PlanFile::read(&first.join("plan/train.json")).unwrap();
    let n = plan.poses.len();
    let picks: Vec<Vec<f64>> = [1, n / 3, 2 * n / 3, n - 2]
        .iter()
        .map(|&i| plan.poses[i].q_deg.clone())
        .collect();
    let rows: Vec<String> = picks
        .iter()
        .map(|q| {
            let v: Vec<String> = q.iter().map(|x| format!("{x:.3}")).collect();
            format!("[{}]", v.join(", "))
        })
        .collect();
    let text = std::fs::read_to_string(&scen).unwrap();
    let scenario = tmp.path().join("teach.toml");
    std::fs::write(
        &scenario,
        format!(
            "{text}\n[operator]\nprobe_tip_mm = [0.0, 0.0, -150.0]\ntremor_mm = 0.05\n\n\
             [[operator.step]]\nkind = \"wait\"\nseconds = 0.5\n\n[[operator.step]]\nkind = \
             \"drag\"\narm = \"vs060\"\nmove_s = 2.5\ndwell_s = 2.0\nposes_deg = [{}]\n",
            rows.join(", ")
        ),
    )
    .unwrap();
    let out = tmp.path().join("taught");
    let (code, stdout, stderr) = run(&[
        "session",
        "--sim",
        p(&scenario),
        "--teach-board",
        "4",
        "--plan-only",
        "--out",
        p(&out),
        "--no-history",
    ]);
    println!("{stdout}\n{stderr}");
    assert_eq!(code, Some(0), "{stderr}");
    let s = robocal::session::SessionFile::load(&out.join("session.json")).unwrap();
    let t = s.teach.as_ref().expect("the teach summary");
    assert_eq!((t.poses, t.views_with_board), (4, 4), "{t:?}");
    // The truth of the scenario (the test may read it): a 9×6-square, 20 mm board placed at
    // (290, -60, 0) mm, so its centre at (380, 0, 0) mm.
    let truth = [380.0, 0.0, 0.0];
    let err = t
        .center_mm
        .iter()
        .zip(truth)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        .sqrt();
    println!(
        "teach-board: board centre {:?} mm, {err:.2} mm from the truth; hand-eye {} at {:?} mm \
         (truth [0, 40, 50]); fx {:.0} px (truth 1500); views agree to {:.2} mm",
        t.center_mm, t.hand_eye, t.hand_eye_xyz_mm, t.fx_px, t.spread_mm
    );
    assert!(err < 10.0, "board centre {err:.1} mm from the truth");
    // The taught joints are the operator's poses (read, never commanded).
    let csv = std::fs::read_to_string(out.join(&t.file)).unwrap();
    let taught = robocal::capture::poses::read_poses_csv("poses.csv", &csv).unwrap();
    let worst = taught
        .iter()
        .zip(&picks)
        .flat_map(|(g, q)| g.q_deg.iter().zip(q).map(|(a, b)| (a - b).abs()))
        .fold(0.0, f64::max);
    assert!(worst < 0.01, "taught joints {worst}° from the operator's");
    // The shell plan is centred on the taught centre.
    let plan = robocal::plan::PlanFile::read(&out.join("plan/train.json")).unwrap();
    let c = &plan.spec["shell"]["center_mm"];
    for k in 0..3 {
        assert!(
            (c[k].as_f64().unwrap() - t.center_mm[k]).abs() < 1e-6,
            "shell centre {c} vs {:?}",
            t.center_mm
        );
    }
    assert!(stderr.contains("teach: 4 hand-guided poses"), "{stderr}");
    // A kinematic cell has no board to teach.
    let (code, _, stderr) = run(&[
        "session",
        "--sim",
        p(&root().join("mocks/scenarios/hospital-vs060-vega.toml")),
        "--teach-board",
        "4",
        "--plan-only",
        "--out",
        p(&tmp.path().join("kin")),
        "--no-history",
    ]);
    assert_ne!(code, Some(0));
    assert!(stderr.contains("for camera sessions"), "{stderr}");
}
