//! Unit tests of both importers (synthetic files in the exact layouts; no real data).
use super::generic::{
    parse_csv, AngleUnit, BodyColumns, CsvMapping, LengthUnit, Orientation, TimeUnit,
};
use super::ipa::{parse_ipa, parse_stamp, series_of, IpaOptions};
use super::serial_robots::{parse_serial_robots, SerialRobotsOptions};
use super::*;

const IPA_HEAD_STD: &str = "Timestamp;Goal x;Goal y;Goal z;Goal roll;Goal pitch;Goal yaw;shoulder_pan_joint;shoulder_lift_joint;elbow_joint;wrist_1_joint;wrist_2_joint;wrist_3_joint;measurement_temperature;measurement_x;measurement_std_x;measurement_y;measurement_std_y;measurement_z;measurement_std_z;measurement_rx;measurement_std_rx;measurement_ry;measurement_std_ry;measurement_rz;measurement_std_rz";
const IPA_HEAD: &str = "Timestamp;Goal x;Goal y;Goal z;Goal roll;Goal pitch;Goal yaw;shoulder_pan_joint;shoulder_lift_joint;elbow_joint;wrist_1_joint;wrist_2_joint;wrist_3_joint;measurement_temperature;measurement_x;measurement_y;measurement_z;measurement_rx;measurement_ry;measurement_rz";

/// `n` rows in the Series A layout (real stamps, 20 s apart, one 15-min pause after row 5).
fn ipa_a(n: usize) -> String {
    let mut s = String::from(IPA_HEAD);
    s.push('\n');
    for i in 0..n {
        let sec = 20 * i + if i > 5 { 900 } else { 0 };
        let stamp = format!(
            "20200714{:02}{:02}{:02}",
            16 + sec / 3600,
            (sec / 60) % 60,
            sec % 60
        );
        let q = 0.01 * i as f64;
        s.push_str(&format!(
            "{stamp};0,36;-0,0002;1,4;1,57;1,57;1,57;{};-1,5708;0,0;-1,5708;{};0,0;23,5;2000,125;-1300,5;{};-90,5;-60,25;-91\n",
            format!("{:.4}", -1.5 + q).replace('.', ","),
            format!("{q:.3}").replace('.', ","),
            format!("{:.5}", 100.25 + i as f64).replace('.', ","),
        ));
    }
    s
}

/// `n` rows in the Series B layout (spreadsheet-mangled stamps, std columns).
fn ipa_b(n: usize) -> String {
    let mut s = String::from(IPA_HEAD_STD);
    s.push('\n');
    for i in 0..n {
        s.push_str(&format!(
            "2,02011E+13;0,4;-0,4;0,8;2,9;1,5;1,5;-0,9;-0,05;-1,9;-1,2;{};-0,001;21,5;-0,5;0,03;-3343;0,04;-427;0,12;-90,1;0,0015;-30;0,0012;-90,4;0,002\n",
            format!("{:.3}", -2.0 + 0.01 * i as f64).replace('.', ",")
        ));
    }
    s
}

#[test]
fn ipa_series_a_layout() {
    let text = ipa_a(12);
    let imp = parse_ipa(
        &text,
        "x/Series_A/measurements_grid.csv",
        &IpaOptions::default(),
    )
    .unwrap();
    assert!(imp.times_real);
    let poses: Vec<_> = imp.dataset.poses().collect();
    assert_eq!(poses.len(), 12);
    let p0 = poses[0];
    // q: rad -> deg
    assert!((p0.q.as_ref().unwrap()[0] - (-1.5f64).to_degrees()).abs() < 1e-9);
    let m = p0.marker.as_ref().unwrap();
    assert_eq!(m.p.unwrap(), [2000.125, -1300.5, 100.25]);
    // scipy Rotation.from_euler('XYZ', [-90.5, -60.25, -91.0], degrees=True)
    let want = [
        0.6810277906032837,
        -0.17852468281583989,
        -0.6857798940568351,
        -0.18448854424844283,
    ];
    let q = m.quat.unwrap();
    assert!((0..4).all(|i| (q[i] - want[i]).abs() < 1e-12), "{q:?}");
    assert_eq!(m.rms, None, "Series A has no std columns");
    assert_eq!(p0.temp_c, Some(23.5));
    assert_eq!(p0.t, 0.0);
    assert_eq!(poses[1].t, 20.0);
    // q_prev = previous q, omitted after the 15-min pause (before row 6)
    assert_eq!(poses[1].q_prev, poses[0].q);
    assert_eq!(poses[6].q_prev, None);
    assert_eq!(poses[7].q_prev, poses[6].q);
    // every 4th pose is validation
    let groups: Vec<&str> = poses.iter().map(|p| p.group.as_deref().unwrap()).collect();
    assert_eq!(&groups[..4], &["train", "train", "train", "validation"]);
    assert_eq!(imp.counts(), (12, 3));
    // header: source, series, created from the first stamp
    let h = &imp.dataset.header;
    assert_eq!(h.created.as_deref(), Some("2020-07-14T16:00:00"));
    assert_eq!(h.extra["source"]["series"], "A");
    assert!(h.notes.as_ref().unwrap().contains("IPA robot-accuracy"));
    assert_eq!(h.robot.model, "ur10");
    assert_eq!(poses[2].extra["src_line"], 4);
    assert!(
        imp.warnings.iter().any(|w| w.contains("pause")),
        "{:?}",
        imp.warnings
    );
}

#[test]
fn ipa_mangled_stamps_use_the_row_index_and_say_so() {
    let imp = parse_ipa(
        &ipa_b(8),
        "Series_B/measurements_joint_configurations.csv",
        &IpaOptions {
            heldout_every: 0,
            ..IpaOptions::default()
        },
    )
    .unwrap();
    assert!(!imp.times_real);
    let poses: Vec<_> = imp.dataset.poses().collect();
    assert_eq!(
        poses.iter().map(|p| p.t).collect::<Vec<_>>(),
        (0..8).map(f64::from).collect::<Vec<_>>()
    );
    assert!(poses.iter().all(|p| p.group.as_deref() == Some("train")));
    // rms = sqrt(0.03² + 0.04² + 0.12²) = 0.13
    assert!((poses[0].marker.as_ref().unwrap().rms.unwrap() - 0.13).abs() < 1e-12);
    assert!(
        poses[1].q_prev.is_some(),
        "no real times: q_prev is the previous row"
    );
    assert!(
        imp.warnings
            .iter()
            .any(|w| w.contains("2,02011E+13") && w.contains(":2:")),
        "{:?}",
        imp.warnings
    );
    assert!(imp
        .warnings
        .iter()
        .any(|w| w.contains("time-based effects")));
    assert!(imp
        .dataset
        .header
        .notes
        .as_ref()
        .unwrap()
        .contains("row index"));
    assert_eq!(imp.dataset.header.extra["source"]["series"], "B");
    assert_eq!(imp.dataset.header.created, None);
}

#[test]
fn ipa_rows_out_of_time_order_are_sorted_with_a_warning() {
    let text = ipa_a(6);
    let mut lines: Vec<&str> = text.lines().collect();
    lines.swap(3, 5);
    let text = lines.join("\n");
    let imp = parse_ipa(&text, "a.csv", &IpaOptions::default()).unwrap();
    let ts: Vec<f64> = imp.dataset.poses().map(|p| p.t).collect();
    assert!(ts.windows(2).all(|w| w[1] >= w[0]), "{ts:?}");
    assert_eq!(imp.dataset.poses().nth(2).unwrap().extra["src_line"], 6);
    assert!(imp.warnings.iter().any(|w| w.contains("backwards")));
}

#[test]
fn stamps_and_series() {
    assert_eq!(parse_stamp("19700101000100"), Some(60.0));
    assert_eq!(parse_stamp("20200714163904"), Some(1_594_744_744.0));
    for bad in ["2,02011E+13", "20201314000000", "2020071416390", ""] {
        assert_eq!(parse_stamp(bad), None, "{bad}");
    }
    assert_eq!(series_of("/tmp/Series_D/measurements_iso_cubes.csv").0, "D");
    assert_eq!(
        series_of("measurements_iso_cubes.csv"),
        ("D".into(), "iso-cubes")
    );
}

fn err_ipa(text: &str) -> String {
    parse_ipa(text, "m.csv", &IpaOptions::default())
        .unwrap_err()
        .to_string()
}

#[test]
fn ipa_errors_name_file_line_column_and_cause() {
    // unknown column: the ones that exist are listed
    let e = err_ipa(&ipa_a(3).replace("elbow_joint", "elbow"));
    assert!(
        e.contains("m.csv:1") && e.contains("\"elbow_joint\"") && e.contains("\"elbow\""),
        "{e}"
    );
    // a value that does not parse
    let e = err_ipa(&ipa_a(3).replacen("2000,125", "23x1", 1));
    assert!(
        e.contains("m.csv:2: column \"measurement_x\"") && e.contains("\"23x1\""),
        "{e}"
    );
    // NaN
    let e = err_ipa(&ipa_a(3).replacen("-1300,5", "NaN", 1));
    assert!(
        e.contains("m.csv:2: column \"measurement_y\"") && e.contains("finite"),
        "{e}"
    );
    // a row with a missing field
    let mut t = ipa_a(3);
    t.push_str("20200714170000;1;2\n");
    let e = err_ipa(&t);
    assert!(e.contains("m.csv:5") && e.contains("3 fields"), "{e}");
    // joints in degrees in a file that should have radians
    let e = err_ipa(&ipa_a(3).replacen(";-1,5708;0,0;-1,5708;", ";-90;0,0;-90;", 1));
    assert!(
        e.contains("m.csv:2") && e.contains("look like degrees"),
        "{e}"
    );
    // positions in metres
    let t = ipa_a(25).replace("2000,125;-1300,5;", "2,000125;-1,3005;");
    let t: String = t
        .lines()
        .map(|l| {
            let mut f: Vec<String> = l.split(';').map(str::to_string).collect();
            if f[0] != "Timestamp" {
                f[16] = "0,119".into();
            }
            f.join(";") + "\n"
        })
        .collect();
    let e = err_ipa(&t);
    assert!(e.contains("look like metres"), "{e}");
    // CRLF line ends: the same line numbers
    let e = err_ipa(&ipa_a(3).replacen("-1300,5", "NaN", 2).replace('\n', "\r\n"));
    assert!(e.contains("m.csv:2: column \"measurement_y\""), "{e}");
    let t = ipa_a(4).replace('\n', "\r\n");
    let t = t
        .replacen("-1300,5", "QQQ", 4)
        .replacen("QQQ", "-1300,5", 3);
    let e = err_ipa(&t);
    assert!(e.contains("m.csv:5: column \"measurement_y\""), "{e}");
    // wrong delimiter
    let e = err_ipa(&ipa_a(3).replace(';', ","));
    assert!(e.contains("m.csv:1"), "{e}");
    // empty
    assert!(err_ipa("").contains("m.csv"));
    // a 7-joint robot
    let mut robot = robot::ur10();
    let mut c = robot.chain.clone().unwrap();
    c.push(c[5].clone());
    robot.chain = Some(c);
    let e = parse_ipa(
        &ipa_a(3),
        "m.csv",
        &IpaOptions {
            heldout_every: 4,
            robot,
        },
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("7 joints"), "{e}");
}

#[test]
fn ipa_round_trip_through_the_reader() {
    let imp = parse_ipa(&ipa_b(30), "b.csv", &IpaOptions::default()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("b.jsonl");
    crate::dataset::write_dataset(&path, &imp.dataset).unwrap();
    let back = crate::dataset::read_dataset(&path).unwrap();
    assert!(back.warnings.is_empty());
    assert_eq!(back.dataset.header, imp.dataset.header);
    for (a, b) in back.dataset.poses().zip(imp.dataset.poses()) {
        let (qa, qb) = (a.q.as_ref().unwrap(), b.q.as_ref().unwrap());
        assert!(qa.iter().zip(qb).all(|(x, y)| (x - y).abs() < 1e-9));
        assert_eq!((a.id, a.t, &a.group), (b.id, b.t, &b.group));
    }
    // and the kinematic observation builder takes every pose
    let (obs, skipped) =
        crate::solve::obs::observations(&back.dataset, 6, crate::solve::obs::Split::All);
    assert_eq!((obs.len(), skipped.len()), (30, 0));
}

fn mapping() -> CsvMapping {
    CsvMapping {
        robot: robot::resolve("ur5e").unwrap(),
        joints: (1..=6).map(|i| format!("j{i}")).collect(),
        joint_unit: AngleUnit::Rad,
        marker: BodyColumns {
            pos: vec!["x".into(), "y".into(), "z".into()],
            orientation: Some(Orientation::Quat {
                cols: vec!["qx".into(), "qy".into(), "qz".into(), "qw".into()],
                order: QuatOrder::Xyzw,
            }),
        },
        length_unit: LengthUnit::M,
        time: Some(("time".into(), TimeUnit::Ms)),
        temp: Some("temp".into()),
        rms: Some("rms".into()),
        reference: None,
        delimiter: b',',
        decimal_comma: false,
        heldout_every: 3,
    }
}

fn csv_text(n: usize) -> String {
    let mut s = String::from("time,j1,j2,j3,j4,j5,j6,x,y,z,qx,qy,qz,qw,temp,rms,rx,ry,rz\n");
    let h = std::f64::consts::FRAC_1_SQRT_2;
    for i in 0..n {
        let a = 0.1 * i as f64;
        s.push_str(&format!(
            "{},{a},-1.2,1.0,0.3,0.2,0.1,0.5,-0.25,{},0,0,{h},{h},22.5,0.00002,10,-35,120\n",
            1000 * i,
            1.0 + 0.001 * i as f64
        ));
    }
    s
}

#[test]
fn generic_csv_units_quaternion_order_time() {
    let imp = parse_csv(&csv_text(25), "g.csv", &mapping()).unwrap();
    assert!(imp.times_real);
    let p: Vec<_> = imp.dataset.poses().collect();
    assert_eq!(p.len(), 25);
    assert_eq!(p[1].t, 1.0);
    assert!((p[1].q.as_ref().unwrap()[0] - 0.1f64.to_degrees()).abs() < 1e-12);
    let m = p[0].marker.as_ref().unwrap();
    assert_eq!(m.p.unwrap(), [500.0, -250.0, 1000.0]);
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let q = m.quat.unwrap();
    assert!(
        (q[0] - h).abs() < 1e-12 && (q[3] - h).abs() < 1e-12,
        "xyzw -> wxyz: {q:?}"
    );
    assert!((m.rms.unwrap() - 0.02).abs() < 1e-12, "rms in m -> mm");
    assert_eq!(p[0].temp_c, Some(22.5));
    assert_eq!(imp.counts(), (25, 8));
    assert_eq!(
        imp.dataset.header.extra["source"]["importer"],
        "robocal import csv"
    );
}

#[test]
fn generic_csv_euler_matches_scipy_and_decimal_comma() {
    let mut map = mapping();
    map.marker.orientation = Some(Orientation::Euler {
        cols: vec!["rx".into(), "ry".into(), "rz".into()],
        seq: "ZYX".parse().unwrap(),
        unit: AngleUnit::Deg,
    });
    map.delimiter = b';';
    map.decimal_comma = true;
    let text = csv_text(3).replace(',', ";").replace('.', ",");
    let imp = parse_csv(&text, "g.csv", &map).unwrap();
    let q = imp
        .dataset
        .poses()
        .next()
        .unwrap()
        .marker
        .as_ref()
        .unwrap()
        .quat
        .unwrap();
    // scipy: R.from_euler('ZYX', [10, -35, 120], degrees=True) as [w, x, y, z]
    let want = [
        0.45234688561385017,
        0.8359042631373821,
        -0.0777950765858491,
        0.3009888436523894,
    ];
    assert!((0..4).all(|i| (q[i] - want[i]).abs() < 1e-12), "{q:?}");
}

#[test]
fn generic_csv_reference_body_and_no_time() {
    let mut map = mapping();
    map.time = None;
    map.reference = Some(BodyColumns {
        pos: vec!["x".into(), "y".into(), "z".into()],
        orientation: Some(Orientation::Euler {
            cols: vec!["rx".into(), "ry".into(), "rz".into()],
            seq: "xyz".parse().unwrap(),
            unit: AngleUnit::Deg,
        }),
    });
    let imp = parse_csv(&csv_text(4), "g.csv", &map).unwrap();
    assert!(!imp.times_real);
    assert!(imp
        .warnings
        .iter()
        .any(|w| w.contains("time-based effects")));
    let p = imp.dataset.poses().nth(1).unwrap();
    assert_eq!(p.t, 1.0);
    let r = p.reference.as_ref().unwrap();
    let rp = r.p.unwrap();
    assert!(
        (0..3).all(|i| (rp[i] - [500.0, -250.0, 1001.0][i]).abs() < 1e-9),
        "{rp:?}"
    );
    let q = r.quat.unwrap();
    let want = [
        0.45234688561385017,
        0.3009888436523894,
        -0.0777950765858491,
        0.8359042631373821,
    ];
    assert!((0..4).all(|i| (q[i] - want[i]).abs() < 1e-12), "{q:?}");
    // the marker is the reference itself here: in its frame it sits at the origin
    let (obs, _) = crate::solve::obs::observations(&imp.dataset, 6, crate::solve::obs::Split::All);
    assert!(obs[0].p.coords.norm() < 1e-9);
}

fn err_csv(text: &str, map: &CsvMapping) -> String {
    parse_csv(text, "g.csv", map).unwrap_err().to_string()
}

#[test]
fn generic_csv_errors() {
    let map = mapping();
    // unknown column
    let mut m = map.clone();
    m.joints[2] = "J3".into();
    let e = err_csv(&csv_text(3), &m);
    assert!(
        e.contains("g.csv:1: column \"J3\"")
            && e.contains("\"j3\"")
            && e.contains("case-sensitive"),
        "{e}"
    );
    // joint count
    let mut m = map.clone();
    m.joints.pop();
    let e = err_csv(&csv_text(3), &m);
    assert!(e.contains("5 columns") && e.contains("6 joints"), "{e}");
    // radians declared as degrees
    let mut m = map.clone();
    m.joint_unit = AngleUnit::Deg;
    let e = err_csv(&csv_text(25), &m);
    assert!(
        e.contains("look like radians") && e.contains("--joint-unit rad"),
        "{e}"
    );
    // only 5 rows: too few to judge, accepted
    assert!(parse_csv(&csv_text(5), "g.csv", &m).is_ok());
    // degrees declared as radians
    let e = err_csv(&csv_text(3).replace("-1.2,", "-90.0,"), &map);
    assert!(
        e.contains("g.csv:2: column \"j2\"") && e.contains("--joint-unit deg"),
        "{e}"
    );
    // metres declared as mm
    let mut m = map.clone();
    m.length_unit = LengthUnit::Mm;
    let e = err_csv(&csv_text(3), &m);
    assert!(
        e.contains("look like metres") && e.contains("--length-unit m"),
        "{e}"
    );
    // quaternion norm
    let e = err_csv(
        &csv_text(3).replace(
            ",0,0,0.7071067811865476,0.7071067811865476,",
            ",0,0,0.7,0.9,",
        ),
        &map,
    );
    assert!(
        e.contains("g.csv:2: column \"qx,qy,qz,qw\"") && e.contains("norm"),
        "{e}"
    );
    // NaN and garbage
    let e = err_csv(&csv_text(3).replace(",22.5,", ",nan,"), &map);
    assert!(
        e.contains("g.csv:2: column \"temp\"") && e.contains("finite"),
        "{e}"
    );
    let e = err_csv(&csv_text(3).replace(",22.5,", ",2 2,"), &map);
    assert!(e.contains("\"2 2\" is not a number"), "{e}");
    // temperature in Kelvin
    let e = err_csv(&csv_text(3).replace(",22.5,", ",295.6,"), &map);
    assert!(e.contains("°C"), "{e}");
    // decimal comma in a ','-separated file: field count
    let e = err_csv(&csv_text(3).replacen("22.5", "22,5", 1), &map);
    assert!(e.contains("g.csv:2") && e.contains("fields"), "{e}");
    // header only
    let e = err_csv("time,j1\n", &map);
    assert!(e.contains("no data rows"), "{e}");
}

#[test]
fn parsers_never_panic_on_garbage() {
    let map = mapping();
    let serial = "step_order,x_t,y_t,z_t,x_dif,y_dif,z_dif,joint_1,joint_2,joint_3,joint_4,joint_5,joint_6\n0,-430.3,-6.27,-98.6,-2.14,-3.52,0.81,-22.9,-43.7,135.4,-94.7,55.4,-5.55\n1,-463.7,-3.94,-104.9,-2.07,-2.88,-0.03,-19.7,-45.9,127.6,-71.4,63.3,-12.7\n".to_string();
    let seeds = [ipa_a(3), ipa_b(3), csv_text(3), serial];
    let mut rng = 12345u64;
    for s in &seeds {
        let b = s.as_bytes();
        for _ in 0..300 {
            let mut v = b.to_vec();
            for _ in 0..4 {
                rng = rng
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let i = (rng >> 33) as usize % v.len();
                v[i] = (rng >> 13) as u8 % 128;
            }
            let t = String::from_utf8_lossy(&v);
            let _ = parse_ipa(&t, "f", &IpaOptions::default());
            let _ = parse_csv(&t, "f", &map);
            let _ = parse_serial_robots(&t, "f", &SerialRobotsOptions::default());
        }
    }
}
