//! `robocal session` end to end on the simulated lab cell (in-process devices, virtual
//! clock): verdict, session.json, report, resume, provenance checks, headless Chromium.
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use robocal::session::{SessionFile, VerdictKind};
use serde_json::Value;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn robocal(args: &[&str]) -> (i32, String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_robocal"))
        .args(args)
        .env("ROBOCAL_LOG", "warn")
        .output()
        .expect("run robocal");
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// One lab session shared by the tests of this module (60 training + 20 held-out points).
fn lab_session() -> &'static (PathBuf, i32, String) {
    static S: OnceLock<(PathBuf, i32, String)> = OnceLock::new();
    S.get_or_init(|| {
        let accept = root().join("accept/research.toml");
        let dir = std::env::temp_dir().join(format!("robocal-session-lab-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let scen = root().join("mocks/scenarios/lab-vs060-optotrak-il600.toml");
        let t0 = std::time::Instant::now();
        let (code, out, err) = robocal(&[
            "session",
            "--sim",
            scen.to_str().unwrap(),
            "--out",
            dir.to_str().unwrap(),
            "--in-process",
            "--poses",
            "60",
            "--heldout-points",
            "20",
            "--note",
            "test session <b>&</b>",
            "--no-history",
            // 60 training poses: the surgical spec's parameter-interval check wants the 120 of
            // the default session; the research spec checks accuracy, skips and worsening.
            "--accept",
            accept.to_str().unwrap(),
        ]);
        println!(
            "session: exit {code} in {:.1} s\n{out}\n{err}",
            t0.elapsed().as_secs_f64()
        );
        assert!(code == 0 || code == 2, "exit {code}: {out}\n{err}");
        (dir, code, out)
    })
}

#[test]
fn lab_session_passes_with_few_skips_and_a_matching_time_prediction() {
    let (dir, code, out) = lab_session();
    let s = SessionFile::load(&dir.join("session.json")).unwrap();
    println!(
        "lab: {} planned, {} skipped, predicted {:.1} s, simulated {:.1} s, verdict {}, held-out {:?} -> {:?}",
        s.poses_planned,
        s.poses_skipped,
        s.predicted_duration_s,
        s.duration_s.unwrap_or(f64::NAN),
        s.verdict_line,
        s.heldout_rms_mm_before,
        s.heldout_rms_mm_after
    );
    assert_eq!(s.verdict, VerdictKind::Pass, "{}", s.verdict_line);
    assert_eq!(*code, 0);
    // The acquisition's own summaries come first on stdout; the session's summary starts
    // with the verdict line.
    assert!(
        out.lines().any(|l| l.starts_with("PASS (research)")),
        "{out}"
    );
    assert!(s.poses_skipped as f64 <= 0.05 * s.poses_planned as f64);
    let d = s.duration_s.unwrap();
    let rel = (s.predicted_duration_s - d).abs() / d;
    assert!(rel <= 0.10, "predicted {} vs {d} s", s.predicted_duration_s);
    assert!(s.heldout_rms_mm_after.unwrap() < s.heldout_rms_mm_before.unwrap());
    // session.json: the verdict is the first key; the datasets carry their SHA-256.
    let text = std::fs::read_to_string(dir.join("session.json")).unwrap();
    let first = text.lines().nth(1).unwrap();
    assert!(
        first.trim_start().starts_with("\"verdict\": \"PASS\""),
        "{first}"
    );
    let v: Value = serde_json::from_str(&text).unwrap();
    for k in [
        "poses_planned",
        "poses_skipped",
        "predicted_duration_s",
        "duration_s",
        "heldout_rms_mm_before",
        "heldout_rms_mm_after",
    ] {
        assert!(v[k].is_number(), "{k}");
    }
    assert_eq!(s.datasets.len(), 2);
    for ds in &s.datasets {
        assert_eq!(
            ds.sha256,
            robocal::session::sha256_file(&dir.join(&ds.path)).unwrap()
        );
    }
    // Every artifact records them; the deploy set reads back.
    for a in [
        "calibrate/calibration.json",
        "diagnose/diagnosis.json",
        "deploy/calibration.json",
    ] {
        let v: Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join(a)).unwrap()).unwrap();
        assert_eq!(v["datasets"], s.dataset_hashes(), "{a}");
    }
    robocal::dataset::CalibrationFile::load(dir.join("deploy/calibration.json")).unwrap();
    let urdf = std::fs::read_to_string(dir.join("deploy/robot.urdf")).unwrap();
    robocal::model::KinematicModel::from_urdf_str(&urdf, None, Some("flange")).unwrap();
    // Robot programs were exported (every move passed the safety path check).
    assert!(dir.join("plan/train.script").is_file() && dir.join("plan/train.pcs").is_file());
}

#[test]
fn report_is_html_with_the_verdict_first_and_refuses_other_sessions_artifacts() {
    let (dir, _, _) = lab_session();
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    assert!(html.starts_with("<!DOCTYPE html>"));
    let body = &html[html.find("<body>").unwrap()..];
    let h1 = body.find("<h1").unwrap();
    assert!(
        body[h1..].starts_with("<h1 class=\"verdict pass\" id=\"verdict\">PASS"),
        "{}",
        &body[h1..h1 + 80]
    );
    assert!(body.contains("SIMULATED"));
    assert!(
        body.contains("test session &lt;b&gt;&amp;&lt;/b&gt;"),
        "note escaped"
    );
    assert!(!html.contains("http://") || html.matches("http://").all(|_| true));
    assert!(!html.contains("<script") && !html.contains("src=\"http"));
    assert!(html.matches("<svg").count() >= 4, "plots inline");
    // A copy whose calibration came from another session: rendering refuses.
    let other = std::env::temp_dir().join(format!("robocal-session-mixed-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&other);
    copy_dir(dir, &other);
    let p = other.join("calibrate/calibration.json");
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    v["datasets"]["train"] = Value::String("0".repeat(64));
    std::fs::write(&p, serde_json::to_string(&v).unwrap()).unwrap();
    let s = SessionFile::load(&other.join("session.json")).unwrap();
    let e = robocal::report::html::render_session(&other, &s)
        .unwrap_err()
        .to_string();
    println!("{e}");
    assert!(
        e.contains("different sessions") && e.contains("calibrate/calibration.json"),
        "{e}"
    );
    // A changed dataset: refused too.
    let mut s2 = s.clone();
    s2.datasets[0].sha256 = "f".repeat(64);
    let e = robocal::report::html::render_session(&other, &s2)
        .unwrap_err()
        .to_string();
    assert!(e.contains("SHA-256"), "{e}");
    let _ = std::fs::remove_dir_all(&other);
}

fn copy_dir(a: &Path, b: &Path) {
    std::fs::create_dir_all(b).unwrap();
    for e in std::fs::read_dir(a).unwrap() {
        let e = e.unwrap();
        let to = b.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to);
        } else {
            std::fs::copy(e.path(), to).unwrap();
        }
    }
}

#[test]
fn resume_redoes_only_the_missing_stages() {
    let (dir, _, _) = lab_session();
    let copy = std::env::temp_dir().join(format!("robocal-session-resume-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&copy);
    copy_dir(dir, &copy);
    // Stopped after the acquisition: drop the later stages and their outputs.
    let p = copy.join("session.json");
    let mut s = SessionFile::load(&p).unwrap();
    let before = s.clone();
    s.stages_done.truncate(3);
    s.save(&p).unwrap();
    for d in ["calibrate", "diagnose", "deploy"] {
        std::fs::remove_dir_all(copy.join(d)).unwrap();
    }
    std::fs::remove_file(copy.join("report.html")).unwrap();
    let (code, out, err) = robocal(&[
        "session",
        "--resume",
        copy.to_str().unwrap(),
        "--no-history",
    ]);
    assert_eq!(code, 0, "{out}\n{err}");
    let after = SessionFile::load(&p).unwrap();
    assert_eq!(after.datasets, before.datasets, "no pose re-acquired");
    assert_eq!(after.measured, before.measured);
    assert!(copy.join("report.html").is_file());
    // A session directory is not overwritten.
    let (code, _, err) = robocal(&[
        "session",
        "--sim",
        root()
            .join("mocks/scenarios/lab-vs060-optotrak-il600.toml")
            .to_str()
            .unwrap(),
        "--out",
        copy.to_str().unwrap(),
    ]);
    assert_eq!(code, 1);
    assert!(err.contains("--resume"), "{err}");
    let _ = std::fs::remove_dir_all(&copy);
}

/// The page in a real browser: headless Chromium dumps the DOM it built and takes a
/// screenshot (kept in target/ for a look). Skips loudly without Chromium.
#[test]
fn report_renders_in_headless_chromium() {
    let (dir, _, _) = lab_session();
    let chromium = ["chromium", "chromium-browser", "google-chrome"]
        .into_iter()
        .find(|c| {
            Command::new(c)
                .arg("--version")
                .output()
                .is_ok_and(|o| o.status.success())
        });
    let Some(chromium) = chromium else {
        crate::common::skipped(
            "no chromium on PATH (Debian package `chromium`): report not checked in a browser",
        );
        return;
    };
    let url = format!("file://{}", dir.join("report.html").display());
    let profile = tempfile::tempdir().unwrap();
    let common = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--no-first-run",
        "--disable-background-networking",
    ];
    let o = Command::new(chromium)
        .args(common)
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .arg("--dump-dom")
        .arg(&url)
        .output()
        .unwrap();
    let dom = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let body = &dom[dom.find("<body").expect("a body")..];
    let first_h1 = &body[body.find("<h1").unwrap()..];
    assert!(
        first_h1.contains("id=\"verdict\"") && first_h1.contains(">PASS"),
        "{}",
        &first_h1[..200.min(first_h1.len())]
    );
    assert!(body.contains("id=\"mode\">SIMULATED<"));
    assert!(body.matches("<svg").count() >= 4);
    let shot = Path::new(env!("CARGO_TARGET_TMPDIR")).join("session-report.png");
    let o = Command::new(chromium)
        .args(common)
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .arg(format!("--screenshot={}", shot.display()))
        .arg("--window-size=1100,1600")
        .arg(&url)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let len = std::fs::metadata(&shot).unwrap().len();
    println!("screenshot {} ({len} bytes)", shot.display());
    assert!(len > 10_000);
}

/// The shipped example device file reads (strict TOML) and describes an arm with a preset.
#[test]
fn example_cell_file_reads() {
    let f =
        robocal::acquire::devices::DevicesFile::read(root().join("examples/CELL.toml")).unwrap();
    let arm = f
        .devices
        .iter()
        .find(|d| d.role == robocal::acquire::devices::Role::Arm)
        .unwrap();
    robocal::model::KinematicModel::preset(arm.model.as_deref().unwrap()).unwrap();
    // The camera cell's example: a camera on the flange and its board with a centre.
    let f = robocal::acquire::devices::DevicesFile::read(root().join("examples/CAMERA-CELL.toml"))
        .unwrap();
    let b = f.board.as_ref().expect("[board]");
    assert!(b.center_mm.is_some());
    assert!(f
        .devices
        .iter()
        .any(|d| d.role == robocal::acquire::devices::Role::Camera
            && d.mount.as_deref() == Some("flange")));
}

/// `--live` is required to move hardware; the device file is validated before anything.
#[test]
fn live_session_needs_live_and_a_valid_device_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s");
    let cell = root().join("examples/CELL.toml");
    let (code, _, err) = robocal(&[
        "session",
        "--devices",
        cell.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 1);
    assert!(err.contains("--live"), "{err}");
    assert!(!out.exists());
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[[device]]\nname = \"a\"\nrole = \"arm\"\nvendor = \"denso\"\nprotocol = \"bcap\"\nadress = \"x\"\n").unwrap();
    let (code, _, err) = robocal(&[
        "session",
        "--devices",
        bad.to_str().unwrap(),
        "--live",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 1);
    assert!(err.contains("adress"), "{err}");
    assert!(!out.exists(), "nothing created for a bad device file");
}

/// A camera cell's device file (a camera, no tracker) makes a camera session; it needs the
/// board and where it is, and says so before anything connects or moves.
#[test]
fn live_camera_session_needs_the_board_and_its_centre() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s");
    let devices = "[[device]]\nname = \"ur5e\"\nrole = \"arm\"\nvendor = \"universal-robots\"\n\
                   protocol = \"rtde\"\nmodel = \"ur5e\"\naddress = \"127.0.0.1\"\n\n\
                   [[device]]\nname = \"cam\"\nrole = \"camera\"\nvendor = \"generic\"\n\
                   protocol = \"opencv\"\naddress = \"0\"\n";
    let run = |text: &str| {
        let f = dir.path().join("cell.toml");
        std::fs::write(&f, text).unwrap();
        robocal(&[
            "session",
            "--devices",
            f.to_str().unwrap(),
            "--live",
            "--yes",
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let (code, _, err) = run(devices);
    assert_eq!(code, 1);
    assert!(
        err.contains("[board]") && err.contains("center_mm"),
        "{err}"
    );
    assert!(!out.exists());
    let (code, _, err) = run(&format!(
        "{devices}\n[board]\ncols = 8\nrows = 5\nsquare_mm = 30.0\n"
    ));
    assert_eq!(code, 1);
    assert!(err.contains("no center_mm"), "{err}");
    assert!(!out.exists());
    // Metres typed for millimetres: refused by the device file itself.
    let (code, _, err) = run(&format!(
        "{devices}\n[board]\ncols = 8\nrows = 5\nsquare_mm = 0.03\ncenter_mm = [0.0, 0.0, 0.0]\n"
    ));
    assert_eq!(code, 1);
    assert!(
        err.contains("square_mm = 0.03") && err.contains("millimetres"),
        "{err}"
    );
}

fn history_checks(loc: &str) {
    use robocal::session::history::History;
    let (dir, _, _) = lab_session();
    let s = SessionFile::load(&dir.join("session.json")).unwrap();
    let mut h = History::open(loc).unwrap();
    let id = h.record(&s).unwrap();
    // Recording the same session again replaces it; a second session of the robot adds one.
    h.record(&s).unwrap();
    let mut s2 = s.clone();
    s2.datasets[0].sha256 = "0".repeat(64);
    s2.created = "2099-01-01T00:00:00Z".into();
    s2.measured.heldout_rms_mm_after = Some(0.5);
    h.record(&s2).unwrap();
    let serial = s.cell.robot_serial.clone().unwrap();
    let rows = h.robot(&serial).unwrap();
    assert_eq!(rows.len(), 2, "{rows:?}");
    assert_eq!(rows[0].session_id, id);
    assert_eq!(rows[0].rms_after, s.measured.heldout_rms_mm_after);
    assert_eq!(rows[1].rms_after, Some(0.5));
    assert_eq!(rows[0].params.len(), s.params.len());
    assert!(h.robot("no-such-robot").unwrap().is_empty());
    let t = robocal::session::history::table(&serial, &rows);
    println!("{t}");
    assert!(t.contains("PASS") && t.contains(&serial));
}

#[test]
fn history_sqlite_and_the_history_command() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("h.sqlite");
    history_checks(db.to_str().unwrap());
    let (_, _, _) = lab_session();
    let svg = dir.path().join("h.svg");
    let (code, out, err) = robocal(&[
        "history",
        "--robot",
        "VS060-SIM-0001",
        "--db",
        db.to_str().unwrap(),
        "--svg",
        svg.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{out}\n{err}");
    println!("{out}");
    assert!(out.contains("2 session(s)") && out.contains("parameter change"));
    assert!(std::fs::read_to_string(&svg).unwrap().starts_with("<svg"));
    let (code, _, err) = robocal(&["history", "--robot", "nobody", "--db", db.to_str().unwrap()]);
    assert_eq!(code, 1);
    assert!(err.contains("no session"), "{err}");
}

/// The same schema on a real PostgreSQL server started here (initdb / pg_ctl as the
/// `postgres` user when running as root). Skips loudly without PostgreSQL.
#[test]
fn history_postgres() {
    let bin = [
        "/usr/local/bin",
        "/usr/lib/postgresql/15/bin",
        "/usr/lib/postgresql/16/bin",
    ]
    .iter()
    .map(Path::new)
    .find(|d| d.join("initdb").exists() && d.join("pg_ctl").exists());
    let Some(bin) = bin else {
        crate::common::skipped(
            "no initdb / pg_ctl (Debian package `postgresql`): PostgreSQL history not tested",
        );
        return;
    };
    let root_user = Command::new("id")
        .arg("-u")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
        .unwrap_or(false);
    let tmp = tempfile::Builder::new()
        .prefix("robocal-pg")
        .tempdir()
        .unwrap();
    let data = tmp.path().join("data");
    let run = |args: &[&str]| -> std::process::Output {
        let mut c = if root_user {
            let mut c = Command::new("runuser");
            c.args(["-u", "postgres", "--"]);
            c.arg(args[0]);
            c.args(&args[1..]);
            c
        } else {
            let mut c = Command::new(args[0]);
            c.args(&args[1..]);
            c
        };
        c.output().unwrap()
    };
    if root_user {
        let _ = Command::new("chown")
            .args(["-R", "postgres", tmp.path().to_str().unwrap()])
            .status();
    }
    let initdb = bin.join("initdb");
    let o = run(&[
        initdb.to_str().unwrap(),
        "-D",
        data.to_str().unwrap(),
        "-U",
        "robocal",
        "--auth=trust",
        "-E",
        "UTF8",
    ]);
    if !o.status.success() {
        crate::common::skipped(format_args!(
            "initdb failed: {}",
            String::from_utf8_lossy(&o.stderr)
        ));
        return;
    }
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let pg_ctl = bin.join("pg_ctl");
    let opts = format!("-p {port} -k {} -h 127.0.0.1", tmp.path().display());
    let log = tmp.path().join("log");
    let o = run(&[
        pg_ctl.to_str().unwrap(),
        "-D",
        data.to_str().unwrap(),
        "-o",
        &opts,
        "-l",
        log.to_str().unwrap(),
        "-w",
        "start",
    ]);
    assert!(
        o.status.success(),
        "pg_ctl start: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    struct Stop<F: Fn()>(F);
    impl<F: Fn()> Drop for Stop<F> {
        fn drop(&mut self) {
            (self.0)()
        }
    }
    let d2 = data.clone();
    let pc = pg_ctl.clone();
    let _stop = Stop(move || {
        let _ = run(&[
            pc.to_str().unwrap(),
            "-D",
            d2.to_str().unwrap(),
            "-m",
            "fast",
            "stop",
        ]);
    });
    let url = format!("postgres://robocal@127.0.0.1:{port}/postgres");
    history_checks(&url);
    println!("PostgreSQL history OK at {url}");
}

#[test]
fn report_on_an_empty_directory_fails() {
    let dir = tempfile::tempdir().unwrap();
    let (code, _, err) = robocal(&["report", "--dir", dir.path().to_str().unwrap()]);
    assert_eq!(code, 1);
    assert!(err.contains("nothing to report"), "{err}");
}

#[test]
fn json_output_of_devices_and_diagnose() {
    let (code, out, err) = robocal(&[
        "devices",
        "--devices",
        root().join("examples/CELL.toml").to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["devices"].as_array().unwrap().len(), 3);
    assert_eq!(v["devices"][0]["role"], "arm");
    let dir = tempfile::tempdir().unwrap();
    let case = root().join("tests/data/kin-compliance-j2");
    let (code, out, err) = robocal(&[
        "diagnose",
        "--data",
        case.join("train.jsonl").to_str().unwrap(),
        "--heldout",
        case.join("heldout.jsonl").to_str().unwrap(),
        "--out",
        dir.path().to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["format"], "robocal-diagnosis/2");
}

#[test]
fn json_output_of_calibrate_kinematics() {
    let dir = tempfile::tempdir().unwrap();
    let case = root().join("tests/data/kin-geometric");
    let (code, out, err) = robocal(&[
        "calibrate",
        "kinematics",
        "--data",
        case.join("train.jsonl").to_str().unwrap(),
        "--heldout",
        case.join("heldout.jsonl").to_str().unwrap(),
        "--out",
        dir.path().to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).expect("stdout is one JSON document");
    assert_eq!(v["format"], "robocal-calibration/1");
}

/// Issue 19: a session can end with the navigation-chain report for a set of CT targets — the
/// robot link is the calibration's bootstrap covariance (issue 29), first order and Monte Carlo agree.
/// A calibration without any uncertainty is refused by `robocal chain` rather than read as a
/// perfect robot.
#[test]
fn session_ends_with_a_chain_report_for_ct_targets() {
    let (dir, _, _) = lab_session();
    let copy = std::env::temp_dir().join(format!("robocal-session-chain-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&copy);
    copy_dir(dir, &copy);
    let inputs = tempfile::tempdir().unwrap();
    let noise = robocal_mocks::navchain::NavNoise::default();
    let mut room = robocal_mocks::navchain::NavWorld::new(41, noise);
    let ([targets, reg, rw], _, _, _) =
        crate::navchain::write_chain_inputs(inputs.path(), &mut room, &noise);
    let (code, out, err) = robocal(&[
        "session",
        "--resume",
        copy.to_str().unwrap(),
        "--no-history",
        "--chain-targets",
        targets.to_str().unwrap(),
        "--chain-registration",
        reg.to_str().unwrap(),
        "--chain-robot-world",
        rw.to_str().unwrap(),
        "--chain-tool-sigma-mm",
        "0.05",
    ]);
    println!("{out}");
    assert_eq!(code, 0, "{out}\n{err}");
    assert!(out.starts_with("PASS"), "the verdict stays first: {out}");
    assert!(
        out.contains("chain report") && out.contains("robot link"),
        "{out}"
    );
    // Issue 29: the robot link is the calibration's bootstrap covariance, not one robot σ.
    assert!(out.contains("bootstrap covariance"), "{out}");
    let cal = robocal::dataset::CalibrationFile::load(copy.join("chain/calibration.json")).unwrap();
    assert!(
        cal.extra["bootstrap"]["covariance"].is_object(),
        "{:?}",
        cal.extra
    );
    let r =
        robocal::navchain::ChainReport::load(&copy.join("chain.json")).expect("chain.json loads");
    assert_eq!(r.targets.len(), 3);
    for t in &r.targets {
        assert!(t.rms_mm.is_finite() && t.rms_mm > 0.0, "{t:?}");
        let rel = (t.rms_mm - t.mc_rms_mm).abs() / t.rms_mm;
        assert!(
            rel < 0.05,
            "{}: first order {} vs MC {}",
            t.name,
            t.rms_mm,
            t.mc_rms_mm
        );
        let robot = t
            .links
            .iter()
            .find(|l| l.link == "robot kinematics")
            .expect("a robot link");
        assert!(
            robot.rms_mm > 0.0,
            "the calibration's covariance reaches the tip: {robot:?}"
        );
    }
    let (code, _, err) = robocal(&[
        "chain",
        "--registration",
        reg.to_str().unwrap(),
        "--robot-world",
        rw.to_str().unwrap(),
        "--targets",
        targets.to_str().unwrap(),
        "--calibration",
        copy.join("deploy/calibration.json").to_str().unwrap(),
        "--joints-deg",
        "0,10,90,0,45,0",
    ]);
    assert_ne!(code, 0);
    assert!(err.contains("no parameter carries an uncertainty"), "{err}");
    // Without the registration the chain flags are refused before anything runs.
    let (code, _, err) = robocal(&[
        "session",
        "--resume",
        copy.to_str().unwrap(),
        "--chain-targets",
        targets.to_str().unwrap(),
    ]);
    assert_ne!(code, 0);
    assert!(err.contains("chain-registration"), "{err}");
    let _ = std::fs::remove_dir_all(&copy);
}

/// Issue 30: the `verify` stage commands the calibrated robot at the held-out targets; on the
/// simulated cell (hidden effects) what it does matches what the calibration predicted.
#[test]
fn lab_session_verifies_by_commanding_the_calibrated_robot() {
    let (dir, _, out) = lab_session();
    let s = SessionFile::load(&dir.join("session.json")).unwrap();
    let v = s.verify.as_ref().expect("verify summary in session.json");
    assert!(out.contains("verified (commanded vs measured)"), "{out}");
    assert!(v.after.poses >= 20 && v.before.poses >= 20, "{v:?}");
    assert!(v.after.rms_mm < 0.2 * v.before.rms_mm, "{v:?}");
    let (cb, ca) = (
        v.coincidence_mm_before.unwrap(),
        v.coincidence_mm_after.unwrap(),
    );
    assert!(v.coincidence_targets >= 5 && ca < 0.2 * cb, "{v:?}");
    let r = v.verified_vs_predicted.unwrap();
    assert!((0.8..=1.2).contains(&r) && !v.flagged, "{v:?}");
    assert_eq!(s.measured.verified_rms_mm_after, Some(v.after.rms_mm));
    // The report shows it: table (both rows, the after RMS as in session.json) and the plot.
    let html = std::fs::read_to_string(dir.join("report.html")).unwrap();
    let t = &html[html
        .find("<table id=\"verify\">")
        .expect("verify table in report.html")..];
    let t = &t[..t.find("</table>").unwrap()];
    assert!(t.contains("before (nominal IK)") && t.contains("after (calibrated IK)"));
    assert!(t.contains(&format!("{:.4}", v.after.rms_mm)), "{t}");
    assert!(html.contains("id=\"plot-verify\"") && html.contains("id=\"verify-vs-predicted\""));
}

/// One session, one geometric fit, each dataset read once: the training and held-out sets are
/// read when they are acquired and handed from stage to stage in memory (calibrate, diagnose,
/// validate and verify share the one identification); the verify run's dataset is read once.
/// Counted in this thread (the session runs in it: the library's command-line entry).
#[test]
fn a_session_identifies_once_and_reads_each_dataset_once() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s");
    let scen = root().join("mocks/scenarios/lab-vs060-optotrak-il600.toml");
    let accept = root().join("accept/research.toml");
    let (fits0, reads0) = (
        robocal::solve::kinematics::identifications_on_this_thread(),
        robocal::dataset::dataset_parses_on_this_thread(),
    );
    let code = robocal::main_with_args([
        "robocal",
        "session",
        "--sim",
        scen.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--in-process",
        "--poses",
        "30",
        "--heldout-points",
        "10",
        "--no-history",
        "--accept",
        accept.to_str().unwrap(),
    ]);
    assert!(code == 0 || code == 2, "exit {code}");
    let s = SessionFile::load(&out.join("session.json")).unwrap();
    assert!(s.stages_done.len() == 8, "{:?}", s.stages_done);
    let fits = robocal::solve::kinematics::identifications_on_this_thread() - fits0;
    let reads = robocal::dataset::dataset_parses_on_this_thread() - reads0;
    // train, validation, verify.
    assert_eq!(fits, 1, "kinematic identifications in one session");
    assert_eq!(
        reads, 3,
        "dataset reads in one session (train, validation, verify)"
    );
}

/// A default session on the shipped scenario `name` (in-process devices, no history) into `out`.
fn default_sim_session(name: &str, out: &Path) -> (i32, String, String) {
    let scen = root().join("mocks/scenarios").join(name);
    let (scen, out) = (scen.to_str().unwrap(), out.to_str().unwrap());
    robocal(&[
        "session",
        "--sim",
        scen,
        "--out",
        out,
        "--in-process",
        "--no-history",
    ])
}

/// Issue 30: the hospital cell's joint 1 has backlash, and two IK branches of one target share
/// its angle, so the move between them is the correction alone, which the backlash it causes
/// reverses. The verify stage reaches such a target through a back-off pose (a fixed approach
/// direction, as real cells do) and the calibrated robot then verifies within 20 % of the
/// held-out prediction; the back-off poses are measured but not scored.
#[test]
fn hospital_session_verifies_within_its_prediction_with_backlash() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s");
    let (code, stdout, err) = default_sim_session("hospital-vs060-vega.toml", &out);
    println!("{stdout}\n{err}");
    assert_eq!(code, 0, "{stdout}\n{err}");
    let s = SessionFile::load(&out.join("session.json")).unwrap();
    let v = s.verify.as_ref().expect("verify summary");
    let r = v.verified_vs_predicted.unwrap();
    println!(
        "hospital verified {:.4} mm vs predicted {:.4} mm: {r:.3}×; {} back-off pose(s)",
        v.after.rms_mm,
        v.predicted_after_rms_mm.unwrap(),
        v.approach_poses
    );
    assert!(r <= 1.2 && !v.flagged, "{v:?}");
    assert!(v.approach_poses >= 1, "{v:?}");
    // The URDF holds the geometry fitted without effects: alone it beats nominal (the
    // diagnosed geometry, fitted with its effects, scored 1.1034 mm alone, worse than nominal).
    let urdf = s
        .deploy_accuracy
        .iter()
        .find(|a| a.artifact == "deploy/robot.urdf")
        .expect("URDF scored");
    let nominal = s.measured.heldout_rms_mm_before.unwrap();
    println!(
        "URDF alone {:.4} mm (nominal {nominal:.4})",
        urdf.heldout_rms_mm
    );
    assert!(urdf.heldout_rms_mm < 0.5 * nominal, "{urdf:?}");
    // The back-off poses are in the run, not among the scored targets.
    let plan: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("plan/verify.json")).unwrap())
            .unwrap();
    let groups: Vec<&str> = plan["poses"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["group"].as_str().unwrap())
        .collect();
    let backoffs = groups.iter().filter(|g| **g == "verify-approach").count();
    assert_eq!(backoffs, v.approach_poses);
    assert!(
        v.after.poses > 0 && v.after.poses <= groups.len() - backoffs,
        "{v:?}"
    );
}
