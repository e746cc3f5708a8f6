//! zenoh's authentication and access control in front of the node, with the shipped example
//! config (`launch/zenoh_access_control.json5`), on loopback: a trusted user calls the services,
//! saves the map and reads the status; a user who logs in but whom no policy names cannot call
//! `save_map` / `load_map`, query the JSON API or read anything the node publishes; a session
//! without valid credentials does not get in at all. And over mutual TLS (`launch/zenoh_tls.json5`
//! with the test certificates of `tests/tls`): only a client whose certificate the node's CA
//! signed gets a session.

#![allow(clippy::unwrap_used)] // test helpers outside #[test] functions unwrap too

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use groupforward::client::{call_service, query_json, wait_for};
use groupforward::config::Config;
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

/// The node on a zenoh peer listening on `endpoint` with the zenoh config file `zenoh_config`,
/// confined to `maps` when given; returns its config, the stop flag and its thread.
fn spawn_node(
    endpoint: &str,
    zenoh_config: &Path,
    maps: Option<&Path>,
) -> (
    Config,
    Arc<AtomicBool>,
    std::thread::JoinHandle<groupforward::node::Result<groupforward_msgs::gf_msgs::NodeStatus>>,
) {
    let mut config = Config::default();
    config.status.period_secs = 0.1;
    config.map.directory = maps.map(|m| m.display().to_string());
    config.zenoh = ZenohSection {
        mode: ZenohMode::Peer,
        listen: vec![endpoint.to_owned()],
        connect: Vec::new(),
        multicast_scouting: false,
        config_file: Some(zenoh_config.display().to_string()),
        ..ZenohSection::default()
    };
    let node_session = open_session(&config.zenoh).unwrap();
    let transport = ZenohTransport::new(node_session, 0, "/", "groupforward").unwrap();
    let shutdown = Arc::new(AtomicBool::new(false));
    let node = {
        let (config, shutdown) = (config.clone(), shutdown.clone());
        std::thread::spawn(move || groupforward::node::run(&config, &transport, &shutdown))
    };
    (config, shutdown, node)
}

#[test]
fn only_trusted_users_reach_the_node_s_services_and_map() {
    let dir = tempfile::tempdir().unwrap();
    let maps = dir.path().join("maps");
    std::fs::create_dir_all(&maps).unwrap();
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let (config, shutdown, node) = spawn_node(&endpoint, &example_config(dir.path()), Some(&maps));
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

/// The test certificates of `tests/tls` (make_certs.sh; their keys are public: tests only).
fn tls_file(name: &str) -> String {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/tls"))
        .join(name)
        .display()
        .to_string()
}

/// The shipped TLS example with the test certificates in place of its paths.
fn tls_example_config(dir: &Path) -> PathBuf {
    let launch = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../launch"));
    let example = std::fs::read_to_string(launch.join("zenoh_tls.json5")).unwrap();
    let moved = example.replace("/etc/groupforward/tls/", &format!("{}/", tls_file("")));
    assert_ne!(moved, example, "the example names its certificate files");
    let path = dir.join("zenoh_tls.json5");
    std::fs::write(&path, moved).unwrap();
    path
}

/// A client session over TLS to `endpoint`, presenting `certificate` (`<name>.pem` and
/// `<name>.key` of tests/tls) when given.
fn tls_client(endpoint: &str, certificate: Option<&str>) -> zenoh::Result<zenoh::Session> {
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", r#""client""#)?;
    config.insert_json5("connect/endpoints", &format!(r#"["{endpoint}"]"#))?;
    config.insert_json5("scouting/multicast/enabled", "false")?;
    let tls = "transport/link/tls";
    config.insert_json5(
        &format!("{tls}/root_ca_certificate"),
        &format!(r#""{}""#, tls_file("ca.pem")),
    )?;
    if let Some(name) = certificate {
        config.insert_json5(&format!("{tls}/enable_mtls"), "true")?;
        config.insert_json5(
            &format!("{tls}/connect_certificate"),
            &format!(r#""{}""#, tls_file(&format!("{name}.pem"))),
        )?;
        config.insert_json5(
            &format!("{tls}/connect_private_key"),
            &format!(r#""{}""#, tls_file(&format!("{name}.key"))),
        )?;
    }
    zenoh::open(config).wait()
}

#[test]
fn over_mutual_tls_only_clients_with_the_ca_s_certificate_get_a_session() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let endpoint = format!("tls/127.0.0.1:{port}");
    let (config, shutdown, node) = spawn_node(&endpoint, &tls_example_config(dir.path()), None);
    let status_key = format!("{}/status", config.api_prefix());
    let list = |session: &zenoh::Session| {
        call_service::<ListInstances>(
            session,
            0,
            &rmw_zenoh::resolve_name("/", "groupforward", "~/list_instances").unwrap(),
            &ListInstancesRequest::default(),
            TIMEOUT,
        )
    };

    // A client with a certificate the node's CA signed: the JSON API, a service, the status.
    let operator = tls_client(&endpoint, Some("client")).unwrap();
    wait_for(
        "the node to answer over TLS",
        Duration::from_secs(10),
        || query_json(&operator, &status_key, Duration::from_millis(300)).ok(),
    )
    .unwrap();
    list(&operator).unwrap();
    assert!(samples_seen(&operator, Duration::from_millis(600)) > 0);

    // Another CA's certificate, no certificate, or no TLS at all: no session reaches the node.
    let refused: [(&str, zenoh::Result<zenoh::Session>); 3] = [
        ("an untrusted CA", tls_client(&endpoint, Some("intruder"))),
        ("no certificate", tls_client(&endpoint, None)),
        ("plain tcp", client(&format!("tcp/127.0.0.1:{port}"), None)),
    ];
    for (who, session) in refused {
        if let Ok(session) = session {
            assert!(
                query_json(&session, &status_key, TIMEOUT).is_err(),
                "{who} queried the JSON API"
            );
            assert!(list(&session).is_err(), "{who} called list_instances");
            assert_eq!(
                samples_seen(&session, Duration::from_millis(300)),
                0,
                "{who} read"
            );
        }
    }

    // The trusted client is still served.
    list(&operator).unwrap();
    shutdown.store(true, Ordering::Relaxed);
    node.join().unwrap().unwrap();
}
