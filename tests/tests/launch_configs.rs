//! Every config in `launch/` parses, and the commented default file says exactly the defaults.

#![allow(clippy::unwrap_used)] // test helpers outside #[test] functions unwrap too

use std::path::Path;

use groupforward::config::Config;

fn launch_dir() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../launch"))
}

#[test]
fn every_launch_config_parses() {
    let mut parsed = 0;
    for entry in std::fs::read_dir(launch_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "yaml") {
            Config::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            parsed += 1;
        }
    }
    assert!(
        parsed >= 2,
        "expected the default and the example configs, parsed {parsed}"
    );
}

#[test]
fn default_config_file_matches_the_built_in_defaults() {
    let from_file = Config::load(&launch_dir().join("groupforward.yaml")).unwrap();
    assert_eq!(from_file, Config::default());
}

#[test]
fn launch_file_names_an_existing_config() {
    let launch = std::fs::read_to_string(launch_dir().join("groupforward.launch.py")).unwrap();
    assert!(launch.contains("'groupforward.yaml'"));
    assert!(launch.contains("'run', '--config'"));
}
