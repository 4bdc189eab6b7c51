//! Helpers shared by the command-line tests: run the binary, a scratch
//! folder per test, and the checks every failure must pass.

use std::path::PathBuf;
use std::process::{Command, Output};

/// Runs `depthmesh` with `args` from the CLI crate's folder.
pub fn depthmesh(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_depthmesh"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("the binary runs")
}

/// A fresh, empty folder for one test (`name` keeps tests apart).
pub fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("depthmesh-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The command succeeded; otherwise show what it said.
#[allow(dead_code)] // not every test file needs it
pub fn ok(output: &Output) {
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
}

/// The `summary.json` a run wrote into `out`.
#[allow(dead_code)] // not every test file needs it
pub fn summary(out: &std::path::Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

/// The command failed with a message containing every one of `needles`, and no panic.
#[allow(dead_code)] // not every test file needs it
pub fn assert_fails_with(output: &Output, needles: &[&str]) {
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        !output.status.success(),
        "expected failure, got success; stderr: {stderr}"
    );
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    for n in needles {
        assert!(stderr.contains(n), "stderr lacks {n:?}: {stderr}");
    }
}

/// `eval trajectory --json` of `estimate` against `reference` (a TUM file
/// or a dataset folder), which must succeed.
#[allow(dead_code)] // not every test file needs it
pub fn eval_json(estimate: &std::path::Path, reference: &std::path::Path) -> serde_json::Value {
    let eval = depthmesh(&[
        "eval",
        "trajectory",
        estimate.to_str().unwrap(),
        reference.to_str().unwrap(),
        "--json",
    ]);
    ok(&eval);
    serde_json::from_slice(&eval.stdout).unwrap()
}
