//! `groupforward model-check` in a fresh process: the ONNX Runtime library is process-global, so the
//! missing- and wrong-library errors are checked here, where each run loads (or fails to load) anew.

use std::path::Path;
use std::process::{Command, Output};

fn manifest() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../models/fixtures/recon_contract.toml")
        .display()
        .to_string()
}

fn model_check(extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_groupforward"))
        .arg("model-check")
        .arg(manifest())
        .args(extra)
        .env_remove("ORT_DYLIB_PATH")
        .output()
        .expect("the groupforward binary runs")
}

#[test]
fn the_fixture_passes_its_contract_check() {
    let out = model_check(&[]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("matches its manifest") && stdout.contains("test fixture"),
        "{stdout}"
    );
}

#[test]
fn a_missing_library_is_a_clear_error_naming_the_install_command() {
    let out = model_check(&["--onnxruntime", "/nonexistent/libonnxruntime.so.1.31.1"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("ONNX Runtime library not found"),
        "{stderr}"
    );
    // Said once, as missing: not wrapped again as a load failure of an empty path.
    assert_eq!(stderr.matches("make setup").count(), 1, "{stderr}");
    assert!(!stderr.contains("cannot load"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn a_file_that_is_not_the_library_is_a_clear_error() {
    let not_a_library = manifest();
    let out = model_check(&["--onnxruntime", &not_a_library]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("cannot load ONNX Runtime"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}
