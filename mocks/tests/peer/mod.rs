//! Shared harness of the public-client peer tests (`*_peer.rs`): where the peer venvs live
//! (installed by `.ci/peers.sh`, one per tool), the skip policy (a loud SKIP outside CI, a
//! failure when `CI` is set), and running a peer script that prints JSON lines.
#![allow(dead_code)] // each test binary uses a part

use std::path::PathBuf;
use std::time::Duration;

/// The workspace root.
pub fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The interpreter of venv `.venv/peers-<venv>`, or `None` (loud SKIP of `what`) when it is
/// missing outside CI. Panics under CI: the peers are part of the gate there.
pub fn python(venv: &str, what: &str) -> Option<PathBuf> {
    let py = workspace().join(format!(".venv/peers-{venv}/bin/python"));
    if py.exists() {
        return Some(py);
    }
    if std::env::var_os("CI").is_some() {
        panic!(
            "CI is set but {} is missing (run .ci/peers.sh)",
            py.display()
        );
    }
    eprintln!(
        "\n*** SKIPPED: {what}: {} missing (run .ci/peers.sh) ***\n",
        py.display()
    );
    // Listed by the README's test command (`.ci/test`) after its summary.
    let dir = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace().join("target"));
    let _ = std::fs::create_dir_all(&dir);
    if let Ok(mut f) = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(dir.join("skipped-tests.txt"))
    {
        use std::io::Write;
        let _ = writeln!(f, "{what}: {} missing (run .ci/peers.sh)", py.display());
    }
    None
}

/// Run `scripts/peers/<script>` with `args` under `py` (killed after `timeout`); asserts it
/// succeeded and returns every stdout line that is a JSON object, in order.
pub async fn run_json_lines(
    py: &PathBuf,
    script: &str,
    args: Vec<String>,
    timeout: Duration,
) -> Vec<serde_json::Value> {
    let mut cmd = tokio::process::Command::new(py);
    cmd.arg(workspace().join("scripts/peers").join(script))
        .args(args)
        .kill_on_drop(true);
    let out = tokio::time::timeout(timeout, cmd.output())
        .await
        .unwrap_or_else(|_| panic!("peer {script} timed out after {timeout:?}"))
        .expect("peer runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "peer {script} failed: {}\nstdout:\n{stdout}\nstderr:\n{stderr}",
        out.status
    );
    stdout
        .lines()
        .filter(|l| l.starts_with('{'))
        .map(|l| {
            serde_json::from_str(l)
                .unwrap_or_else(|e| panic!("peer {script}: bad JSON line {l:?}: {e}"))
        })
        .collect()
}
