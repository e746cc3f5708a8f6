use super::refer::on_query_pool;
use super::*;
use crate::graph::SceneMap;
use crate::refer::ReferScene;
use groupforward_msgs::gf_msgs::Instance;
use groupforward_msgs::vision_msgs::ObjectHypothesis;

#[test]
fn a_query_answers_on_the_previous_snapshot_only_while_the_output_thread_takes_the_new_one() {
    let shared = Mutex::new(Shared::default());
    let lock = || shared.lock().unwrap_or_else(|e| panic!("{e}"));
    let snapshot = |f: fn(&Mutex<Shared>) -> std::result::Result<Arc<ReferScene>, String>| {
        f(&shared).unwrap_or_else(|e| panic!("{e}"))
    };
    lock().snapshot_taker = true;
    lock().set_map(SceneMap::default());
    let first = snapshot(current_snapshot);
    assert_eq!(lock().refer_scene_generation, 1);
    // A window changed the map and the output thread will take its snapshot: the query
    // does not wait for it.
    lock().refresh_instances();
    snapshot_due(&mut lock());
    assert!(Arc::ptr_eq(&snapshot(query_snapshot), &first));
    assert_eq!(lock().refer_scene_generation, 1);
    // The output thread took it: the query reads the new one.
    let taken = snapshot(current_snapshot);
    assert!(lock().refer_scene_building.is_none());
    assert!(Arc::ptr_eq(&snapshot(query_snapshot), &taken));
    assert!(!Arc::ptr_eq(&taken, &first));
    // Promised too long ago (a stalled output thread): the query takes it itself.
    lock().refresh_instances();
    snapshot_due(&mut lock());
    if let Some((_, since)) = lock().refer_scene_building.as_mut() {
        *since -= std::time::Duration::from_secs_f64(SNAPSHOT_DUE_SECS + 0.5);
    }
    assert!(!Arc::ptr_eq(&snapshot(query_snapshot), &taken));
    let current = |s: &Shared| s.refer_scene_generation == s.map_generation;
    assert!(current(&lock()));
    // No output thread: nothing is promised, and a query after a change takes it.
    lock().snapshot_taker = false;
    lock().refresh_instances();
    snapshot_due(&mut lock());
    assert!(lock().refer_scene_building.is_none());
    snapshot(query_snapshot);
    assert!(current(&lock()));
}

#[test]
fn a_window_fused_outside_the_lock_is_installed_unless_load_map_replaced_the_map_meanwhile() {
    let mut s = Shared::default();
    s.set_map(SceneMap::default());
    // The worker copies the map at generation 1 and fuses one instance into the copy.
    let copied_at = s.map_generation;
    let fused = vec![named("inst_000001", "chair")];
    assert!(s.install_fused(
        copied_at,
        SceneMap::default(),
        (fused.clone(), Default::default()),
        BoxCache::default()
    ));
    assert_eq!(s.map_generation, copied_at + 1);
    assert_eq!(s.instances.len(), 1);
    // The next window copies generation 2, but a load_map replaces the map before it is
    // installed: the window is dropped and counted, the loaded map stays.
    let copied_at = s.map_generation;
    s.set_map(SceneMap::default());
    let loaded = s.map_generation;
    assert!(!s.install_fused(
        copied_at,
        SceneMap::default(),
        (fused, Default::default()),
        BoxCache::default()
    ));
    assert_eq!((s.map_generation, s.windows_superseded), (loaded, 1));
    assert!(
        s.instances.is_empty(),
        "the loaded (empty) map's list stays"
    );
}

#[test]
fn answers_render_on_their_own_threads_while_rayons_global_pool_is_busy() {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicBool, Ordering};
    let release = AtomicBool::new(false);
    let busy = AtomicBool::new(false);
    // Held at most this long, so a render queued behind them fails the test, not hangs it.
    let started = std::time::Instant::now();
    let held = std::time::Duration::from_secs(3);
    std::thread::scope(|scope| {
        // The window worker's HDBSCAN: every global-pool thread held until released.
        scope.spawn(|| {
            (0..rayon::current_num_threads() * 4)
                .into_par_iter()
                .for_each(|_| {
                    busy.store(true, Ordering::Release);
                    while !release.load(Ordering::Acquire) && started.elapsed() < held {
                        std::thread::yield_now();
                    }
                });
        });
        while !busy.load(Ordering::Acquire) {
            std::thread::yield_now();
        }
        // An answer's parallel render still runs, on the query pool's threads.
        let names: Vec<String> = on_query_pool(|| {
            (0..8)
                .into_par_iter()
                .map(|_| std::thread::current().name().unwrap_or("").to_owned())
                .collect()
        });
        release.store(true, Ordering::Release);
        assert!(
            started.elapsed() < held,
            "the render waited for the global pool"
        );
        assert!(
            names.iter().all(|n| n.starts_with("gf-query-")),
            "{names:?}"
        );
    });
}

fn named(id: &str, best: &str) -> Instance {
    Instance {
        id: id.into(),
        hypotheses: vec![
            ObjectHypothesis {
                class_id: best.into(),
                score: 0.7,
            },
            ObjectHypothesis {
                class_id: "table".into(),
                score: 0.2,
            },
        ],
        ..Default::default()
    }
}

#[test]
fn map_paths_stay_inside_the_configured_directory() {
    let mut s = Shared {
        map_file: Some("/var/robot/map.gfmap".into()),
        ..Shared::default()
    };
    // No directory: any path, as before; an empty request names map.file.
    assert_eq!(map_path(&s, "../x.gfmap").unwrap(), "../x.gfmap");
    assert_eq!(map_path(&s, "").unwrap(), "/var/robot/map.gfmap");
    s.map_directory = Some("/data/maps".into());
    assert_eq!(
        map_path(&s, "kitchen.gfmap").unwrap(),
        "/data/maps/kitchen.gfmap"
    );
    assert_eq!(
        map_path(&s, "/data/maps/a/b.gfmap").unwrap(),
        "/data/maps/a/b.gfmap"
    );
    for outside in [
        "../etc/passwd",
        "a/../../x.gfmap",
        "/etc/x.gfmap",
        "/data/mapsx/y.gfmap",
        "/data/maps/../z.gfmap",
    ] {
        let refused = map_path(&s, outside).unwrap_err();
        assert!(
            refused.contains("outside the map directory"),
            "{outside}: {refused}"
        );
    }
    assert_eq!(map_path(&s, "").unwrap(), "/var/robot/map.gfmap");
}

/// A map of three cubes of 27 Gaussians, 2 m apart along x, each fused as its own instance.
fn three_cubes() -> SceneMap {
    use crate::frame::WindowInstance;
    use crate::graph::FusionParams;
    let cube = |x: f32| {
        let mut g = crate::recon::gaussians::Gaussians::with_dims(0, 0);
        for i in 0..27 {
            let offset = glam::Vec3::new((i % 3) as f32, (i / 3 % 3) as f32, (i / 9) as f32);
            g.push(
                glam::Vec3::new(x, 0.0, 0.5) + offset * 0.1,
                0.9,
                glam::Vec3::splat(0.02),
                glam::Quat::IDENTITY,
                glam::Vec3::ONE,
                &[],
                &[],
            );
        }
        g
    };
    let mut map = SceneMap::new(FusionParams::default());
    let window = (0..3)
        .map(|k| WindowInstance {
            gaussians: cube(2.0 * k as f32),
            prototype: vec![1.0, k as f32],
            support: 27,
        })
        .collect();
    map.fuse(window, &[], 1).unwrap();
    map
}

#[test]
fn an_answer_carries_the_published_box_from_the_list_made_with_the_messages() {
    let shared = Mutex::new(Shared::default());
    let mut s = shared.lock().unwrap();
    s.set_map(three_cubes());
    assert_eq!(s.instances.len(), 3);
    assert_eq!(s.query_list.len(), 3);
    // The snapshot takes that list: a box changed in it (and only there) is the one queries see.
    let moved = &s.instances[1].id.clone();
    Arc::make_mut(&mut s.query_list)
        .get_mut(moved)
        .unwrap()
        .0
        .centre
        .x += 5.0;
    drop(s);
    let scene = current_snapshot(&shared).unwrap();
    let s = shared.lock().unwrap();
    for message in &s.instances {
        let published = crate::refer::response::pose_box(&message.pose, &message.size);
        let node = scene.node(&message.id).unwrap();
        let shift = if &message.id == moved { 5.0 } else { 0.0 };
        assert!(
            (node.bbox.centre.x - published.centre.x - shift).abs() < 1e-9
                && (node.bbox.size - published.size).length() < 1e-9,
            "{}: {:?} against {:?}",
            message.id,
            node.bbox,
            published
        );
    }
}

#[test]
fn cached_boxes_are_refitted_exactly_where_the_gaussians_changed() {
    let mut map = three_cubes();
    let mut cache = BoxCache::default();
    let first = instance_messages_cached(&map, None, 3, &mut cache);
    assert_eq!(first, instance_messages(&map, None, 3));
    // The middle instance moves by a metre; the others stay.
    for m in &mut map.instances[1].gaussians.means {
        m.x += 1.0;
    }
    let second = instance_messages_cached(&map, None, 3, &mut cache);
    assert_eq!(second, instance_messages(&map, None, 3), "no stale box");
    assert!((second[1].pose.position.x - first[1].pose.position.x - 1.0).abs() < 1e-6);
    assert_eq!(second[0], first[0]);
    assert_eq!(second[2], first[2]);
    // An instance that left the map leaves the cache.
    map.instances.remove(2);
    instance_messages_cached(&map, None, 3, &mut cache);
    assert_eq!(cache.0.len(), 2);
}

fn shared() -> Mutex<Shared> {
    Mutex::new(Shared {
        instances: vec![
            named("inst_000001", "chair"),
            named("inst_000002", "armchair"),
            named("inst_000003", "lamp"),
        ],
        ..Shared::default()
    })
}

fn list(shared: &Mutex<Shared>, filter: &str) -> Vec<String> {
    let request = cdr::encode(&ListInstancesRequest {
        label_filter: filter.into(),
    })
    .unwrap();
    let reply: ListInstancesResponse =
        cdr::decode(&handle_list(shared, &request).unwrap()).unwrap();
    reply.instances.into_iter().map(|i| i.id).collect()
}

#[test]
fn list_filters_by_the_best_label_only() {
    let shared = shared();
    assert_eq!(list(&shared, "").len(), 3);
    // A substring of the best hypothesis: both chairs; `table` is only a second hypothesis.
    assert_eq!(list(&shared, "chair"), ["inst_000001", "inst_000002"]);
    assert_eq!(list(&shared, "lamp"), ["inst_000003"]);
    assert!(list(&shared, "table").is_empty());
}

#[test]
fn get_finds_by_id_and_says_when_it_does_not() {
    let shared = shared();
    let get = |id: &str| -> GetInstanceResponse {
        let request = cdr::encode(&GetInstanceRequest { id: id.into() }).unwrap();
        cdr::decode(&handle_get(&shared, &request).unwrap()).unwrap()
    };
    let found = get("inst_000003");
    assert!(found.found);
    assert_eq!(found.instance.hypotheses[0].class_id, "lamp");
    let missing = get("inst_000042");
    assert!(!missing.found);
    assert!(missing.instance.id.is_empty());
    assert!(handle_get(&shared, b"garbage").is_err());
}

#[test]
fn the_json_api_serves_instances_and_status_and_names_what_it_serves() {
    let shared = shared();
    let instances: serde_json::Value =
        serde_json::from_str(&handle_json(&shared, "instances", "").unwrap()).unwrap();
    let ids: Vec<&str> = instances
        .as_array()
        .unwrap()
        .iter()
        .map(|i| i["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids, ["inst_000001", "inst_000002", "inst_000003"]);
    assert_eq!(instances[2]["hypotheses"][0]["class_id"], "lamp");
    let status: serde_json::Value =
        serde_json::from_str(&handle_json(&shared, "status", "").unwrap()).unwrap();
    assert!(status["cameras"].is_array());
    let unknown = handle_json(&shared, "graph", "").unwrap_err();
    assert!(
        unknown.contains("status, instances, scene_graph, refer"),
        "{unknown}"
    );
}
