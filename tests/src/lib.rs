//! End-to-end tests live in tests/; this holds what several of them share.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The repository's root.
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Run `script` with the project's test venv (`make setup`) and return its stdout; panics with
/// its stderr when it fails.
pub fn venv_python(script: &str) -> Vec<u8> {
    let python = root().join(".venv/bin/python");
    let output = Command::new(&python)
        .arg("-c")
        .arg(script)
        .output()
        .unwrap_or_else(|e| panic!("{}: {e} (run `make setup`)", python.display()));
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    output.stdout
}
