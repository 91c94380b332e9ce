//! Helpers shared by the integration-test modules of the one test binary.
use std::path::Path;

/// The project root (the root crate's manifest directory).
pub fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Runs the robocal command line in process; returns its exit code.
pub fn cli(args: &[&str]) -> i32 {
    let mut v = vec!["robocal".to_string()];
    v.extend(args.iter().map(|s| s.to_string()));
    robocal::cli::run(v)
}

/// A path as `&str` (test paths are UTF-8).
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}
