//! zenoh's authentication and access control in front of the node, with the shipped example
//! config (`launch/zenoh_access_control.json5`), on loopback: a trusted user calls the services,
//! saves the map and reads the status; a user who logs in but whom no policy names cannot call
//! `save_map` / `load_map`, query the JSON API or read anything the node publishes; a session
//! without valid credentials does not get in at all.

#![allow(clippy::unwrap_used)] // test helpers outside #[test] functions unwrap too

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use groupforward::config::Config;
use groupforward::demo::{call_service, query_json, wait_for};
use groupforward::transport::{open_session, ZenohMode, ZenohSection, ZenohTransport};
use groupforward_msgs::gf_msgs::{ListInstancesRequest, MapPathRequest};
use groupforward_msgs::rmw_zenoh;
use groupforward_msgs::services::{ListInstances, LoadMap, SaveMap};
use zenoh::Wait;

const USERS: &str = "robot:robot-secret\noperator:operator-secret\nintruder:intruder-secret\n";
const TIMEOUT: Duration = Duration::from_secs(2);

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// The shipped example, its password dictionary moved to `dir`.
fn example_config(dir: &Path) -> PathBuf {
    let launch = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../launch"));
    let example = std::fs::read_to_string(launch.join("zenoh_access_control.json5")).unwrap();
    let users = dir.join("zenoh_users.txt");
    std::fs::write(&users, USERS).unwrap();
    let moved = example.replace(
        "/etc/groupforward/zenoh_users.txt",
        &users.display().to_string(),
    );
    assert_ne!(moved, example, "the example names its dictionary file");
    let path = dir.join("zenoh.json5");
    std::fs::write(&path, moved).unwrap();
    path
}

/// A client session to `endpoint`, logging in as `user` when given.
fn client(endpoint: &str, user: Option<(&str, &str)>) -> zenoh::Result<zenoh::Session> {
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", r#""client""#)?;
    config.insert_json5("connect/endpoints", &format!(r#"["{endpoint}"]"#))?;
    config.insert_json5("scouting/multicast/enabled", "false")?;
    if let Some((name, password)) = user {
        config.insert_json5(
            "transport/auth/usrpwd",
            &format!(r#"{{ user: "{name}", password: "{password}" }}"#),
        )?;
    }
    zenoh::open(config).wait()
}

/// Samples of anything the node publishes that `session` receives in `window`.
fn samples_seen(session: &zenoh::Session, window: Duration) -> usize {
    let seen = Arc::new(AtomicUsize::new(0));
    let counter = seen.clone();
    let subscriber = session
        .declare_subscriber("0/**")
        .callback(move |_| {
            counter.fetch_add(1, Ordering::Relaxed);
        })
        .wait()
        .unwrap();
    std::thread::sleep(window);
    drop(subscriber);
    seen.load(Ordering::Relaxed)
}

#[test]
fn only_trusted_users_reach_the_node_s_services_and_map() {
    let dir = tempfile::tempdir().unwrap();
    let maps = dir.path().join("maps");
    std::fs::create_dir_all(&maps).unwrap();
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let mut config = Config::default();
    config.status.period_secs = 0.1;
    config.map.directory = Some(maps.display().to_string());
    config.zenoh = ZenohSection {
        mode: ZenohMode::Peer,
        listen: vec![endpoint.clone()],
        connect: Vec::new(),
        multicast_scouting: false,
        config_file: Some(example_config(dir.path()).display().to_string()),
        ..ZenohSection::default()
    };
    let node_session = open_session(&config.zenoh).unwrap();
    let transport = ZenohTransport::new(node_session, 0, "/", "groupforward").unwrap();
    let shutdown = Arc::new(AtomicBool::new(false));
    let node = {
        let (config, shutdown) = (config.clone(), shutdown.clone());
        std::thread::spawn(move || groupforward::node::run(&config, &transport, &shutdown))
    };
    let status_key = format!("{}/status", config.api_prefix());
    let service = |name: &str| {
        rmw_zenoh::resolve_name(&config.node.namespace, &config.node.name, name).unwrap()
    };
    let save = |session: &zenoh::Session, path: &str| {
        call_service::<SaveMap>(
            session,
            0,
            &service("~/save_map"),
            &MapPathRequest { path: path.into() },
            TIMEOUT,
        )
    };

    // A trusted user: the JSON API, a service, a save and a load, and the published status.
    let operator = client(&endpoint, Some(("operator", "operator-secret"))).unwrap();
    wait_for(
        "the node to answer the operator",
        Duration::from_secs(10),
        || query_json(&operator, &status_key, Duration::from_millis(300)).ok(),
    )
    .unwrap();
    call_service::<ListInstances>(
        &operator,
        0,
        &service("~/list_instances"),
        &ListInstancesRequest::default(),
        TIMEOUT,
    )
    .unwrap();
    let saved = save(&operator, "operator.gfmap").unwrap();
    assert!(saved.success, "{}", saved.message);
    assert!(maps.join("operator.gfmap").exists());
    let loaded = call_service::<LoadMap>(
        &operator,
        0,
        &service("~/load_map"),
        &MapPathRequest {
            path: "operator.gfmap".into(),
        },
        TIMEOUT,
    )
    .unwrap();
    assert!(loaded.success, "{}", loaded.message);
    assert!(samples_seen(&operator, Duration::from_millis(600)) > 0);

    // Logged in, but no policy names the user: nothing goes through either way.
    let intruder = client(&endpoint, Some(("intruder", "intruder-secret"))).unwrap();
    assert!(query_json(&intruder, &status_key, TIMEOUT).is_err());
    assert!(save(&intruder, "intruder.gfmap").is_err());
    assert!(!maps.join("intruder.gfmap").exists(), "the intruder saved");
    assert!(call_service::<LoadMap>(
        &intruder,
        0,
        &service("~/load_map"),
        &MapPathRequest {
            path: "operator.gfmap".into(),
        },
        TIMEOUT,
    )
    .is_err());
    assert_eq!(samples_seen(&intruder, Duration::from_millis(600)), 0);

    // A wrong password or none: the session is refused, or reaches nothing.
    for user in [Some(("operator", "guess")), None] {
        if let Ok(stranger) = client(&endpoint, user) {
            assert!(query_json(&stranger, &status_key, TIMEOUT).is_err());
            assert!(save(&stranger, "stranger.gfmap").is_err());
        }
    }
    assert!(!maps.join("stranger.gfmap").exists());

    // The trusted user is still served after all that.
    assert!(save(&operator, "again.gfmap").unwrap().success);
    shutdown.store(true, Ordering::Relaxed);
    node.join().unwrap().unwrap();
}
