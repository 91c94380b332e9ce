//! Helpers shared by the integration-test modules of the one test binary.
use std::path::Path;

/// The project root (the root crate's manifest directory).
pub fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The real UR10 series (IPA Series A: `train.jsonl` + `heldout.jsonl`) from
/// `$ROBOCAL_REAL_DATA` or `../shared/data/real-ur10-ipa-grid`; `None`, after saying SKIPPED
/// loudly that `what` is not measured, when absent.
pub fn real_ur10_dir(what: &str) -> Option<std::path::PathBuf> {
    let dir = std::env::var_os("ROBOCAL_REAL_DATA")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| root().join("../shared/data/real-ur10-ipa-grid"));
    if dir.join("train.jsonl").is_file() && dir.join("heldout.jsonl").is_file() {
        return Some(dir);
    }
    skipped(format_args!(
        "real UR10 data absent ({}); not measured: {what}",
        dir.display()
    ));
    None
}

/// Runs the robocal command line in process; returns its exit code.
pub fn cli(args: &[&str]) -> i32 {
    let mut v = vec!["robocal".to_string()];
    v.extend(args.iter().map(|s| s.to_string()));
    robocal::main_with_args(v)
}

/// `robocal diagnose --data DATA --heldout HELD --out OUT` in process; its exit code.
pub fn diagnose_cli(data: &Path, held: &Path, out: &Path) -> i32 {
    cli(&[
        "diagnose",
        "--data",
        s(data),
        "--heldout",
        s(held),
        "--out",
        s(out),
    ])
}

/// The arguments `predict --calibration CAL --data DATA --out OUT`.
pub fn predict_argv<'a>(cal: &'a Path, data: &'a Path, out: &'a Path) -> [&'a str; 7] {
    [
        "predict",
        "--calibration",
        s(cal),
        "--data",
        s(data),
        "--out",
        s(out),
    ]
}

/// `cmd… --data DATA --heldout HELD --out OUT` (then `extra`): a training + held-out run's
/// arguments.
pub fn heldout_argv<'a>(
    cmd: &[&'a str],
    data: &'a Path,
    held: &'a Path,
    out: &'a Path,
    extra: &[&'a str],
) -> Vec<&'a str> {
    let mut v = cmd.to_vec();
    v.extend(["--data", s(data), "--heldout", s(held), "--out", s(out)]);
    v.extend_from_slice(extra);
    v
}

/// `robocal predict --calibration CAL --data DATA --out OUT` in process; its exit code.
pub fn predict_cli(cal: &Path, data: &Path, out: &Path) -> i32 {
    cli(&predict_argv(cal, data, out))
}

/// Runs the robocal binary (stdin closed, `ROBOCAL_LOG=warn`); returns its exit code, stdout
/// and stderr.
pub fn bin(args: &[&str]) -> (Option<i32>, String, String) {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_robocal"))
        .env("ROBOCAL_LOG", "warn")
        .stdin(std::process::Stdio::null())
        .args(args)
        .output()
        .unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// A path as `&str` (test paths are UTF-8).
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A check that could not run here (real data, a peer or a Debian package absent): said loudly
/// on stderr and recorded in `target/skipped-tests.txt`, which the README's test command
/// (`.ci/test`) lists after its summary, so a skipped check never reads as a pass.
pub fn skipped(what: impl std::fmt::Display) {
    eprintln!("\n*** SKIPPED: {what} ***\n");
    record_skip(&root().join("target"), &what.to_string());
}

/// Append one line to `<target>/skipped-tests.txt` (best effort: a test never fails on it).
pub fn record_skip(target: &Path, what: &str) {
    use std::io::Write;
    let dir = std::env::var_os("CARGO_TARGET_DIR")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| target.to_path_buf());
    let _ = std::fs::create_dir_all(&dir);
    if let Ok(mut f) = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(dir.join("skipped-tests.txt"))
    {
        let _ = writeln!(f, "{}", what.replace('\n', " "));
    }
}

/// `robocal import handeye` options for the real KUKA set (RWHE-Calib `kuka_1` in `dir`: row-major
/// 4×4 in metres, 28×17 inner corners of 20 mm) read in `direction`, written to `out`, every 4th
/// view to `heldout` when given.
pub fn kuka1_import_options(
    dir: &Path,
    out: &Path,
    heldout: Option<&Path>,
    direction: robocal::import::handeye::Direction,
) -> robocal::import::handeye::HandeyeOptions {
    robocal::import::handeye::HandeyeOptions {
        images: dir.to_path_buf(),
        poses: dir.join("RobotPosesVec.txt"),
        reading: robocal::import::handeye::Reading {
            layout: robocal::import::handeye::Layout::Matrix4 { col_major: false },
            unit: robocal::import::generic::LengthUnit::M,
            direction,
        },
        target: robocal::dataset::TargetHeader {
            kind: "chessboard".into(),
            cols: 28,
            rows: 17,
            square_mm: 20.0,
            marker_mm: None,
            dictionary: None,
        },
        mount: robocal::solve::camera::Mount::Flange,
        out: out.to_path_buf(),
        heldout_every: if heldout.is_some() { 4 } else { 0 },
        heldout: heldout.map(Path::to_path_buf),
    }
}
