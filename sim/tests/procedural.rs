#![allow(clippy::unwrap_used)]
//! Procedural scenes obey the physical rules, checked on the geometry itself (signed distances),
//! not on the bookkeeping that placed the objects.

use glam::DVec3;
use groupforward_sim::procedural::{generate, Split};
use groupforward_sim::render::Scene;
use groupforward_sim::scene::is_free;

fn scenes(split: Split, count: u64) -> Vec<(String, Scene)> {
    (0..count)
        .map(|i| {
            let file = generate(split, i).unwrap();
            let scene = file
                .build()
                .unwrap_or_else(|e| panic!("{}: {e}", file.name));
            (file.name, scene)
        })
        .collect()
}

#[test]
fn objects_stand_on_the_floor_or_on_their_support() {
    let mut supported = 0;
    for (name, scene) in scenes(Split::Train, 40) {
        for object in &scene.objects {
            let (lo, _) = object.bounds();
            match object.support {
                None => assert!(lo.z.abs() < 1e-9, "{name}: {} floats", object.instance_id),
                Some(id) => {
                    let support = scene.objects.iter().find(|o| o.instance_id == id).unwrap();
                    // Just below the object's base is the support's surface.
                    let below = DVec3::new(object.position.x, object.position.y, lo.z - 1e-3);
                    let d = support.distance(below);
                    assert!(
                        d.abs() < 2e-3,
                        "{name}: object {} is {d} m from its support {id}",
                        object.instance_id
                    );
                    supported += 1;
                }
            }
        }
    }
    assert!(
        supported >= 20,
        "only {supported} supported objects in 40 scenes"
    );
}

#[test]
fn no_two_objects_interpenetrate() {
    for (name, scene) in scenes(Split::Val, 25) {
        for a in &scene.objects {
            let (lo, hi) = a.bounds();
            let n = 7;
            for i in 0..n {
                for j in 0..n {
                    for k in 0..n {
                        let s = DVec3::new(i as f64, j as f64, k as f64) / (n - 1) as f64;
                        let p = lo + (hi - lo) * s;
                        if a.distance(p) > -2e-3 {
                            continue;
                        }
                        for b in scene
                            .objects
                            .iter()
                            .filter(|b| b.instance_id != a.instance_id)
                        {
                            assert!(
                                b.distance(p) > -2e-3,
                                "{name}: objects {} and {} share the point {p}",
                                a.instance_id,
                                b.instance_id
                            );
                        }
                    }
                }
            }
        }
    }
}

#[test]
fn several_instances_of_a_class_are_the_norm() {
    let all = scenes(Split::Train, 40);
    let with_repeats = all
        .iter()
        .filter(|(_, scene)| {
            let mut counts = std::collections::BTreeMap::new();
            for o in &scene.objects {
                *counts.entry(o.class_id).or_insert(0) += 1;
            }
            counts.values().any(|c| *c >= 2)
        })
        .count();
    assert!(
        with_repeats * 10 >= all.len() * 7,
        "{with_repeats}/{}",
        all.len()
    );
}

#[test]
fn the_random_walk_stays_in_free_space_and_sees_objects() {
    for index in 0..10 {
        let file = generate(Split::Benchmark, index).unwrap();
        let scene = file.build().unwrap();
        let poses = file.robot_poses().unwrap();
        assert_eq!(poses.len(), 60);
        for pose in &poses {
            assert!(is_free(&scene, pose.position), "{}: {pose:?}", file.name);
        }
        let moved = (poses[59].position - poses[0].position).length();
        assert!(moved > 0.1, "{} stands still", file.name);
    }
}

#[test]
fn every_scene_of_a_large_sample_builds_with_a_walkable_trajectory() {
    for split in Split::ALL {
        for index in 0..400 {
            let file = generate(split, index).unwrap();
            let poses = file.robot_poses();
            assert!(poses.is_ok(), "{}: {:?}", file.name, poses.err());
        }
    }
}

#[test]
fn procedural_scenes_round_trip_through_toml() {
    let file = generate(Split::Train, 11).unwrap();
    let text = file.to_toml().unwrap();
    let back: groupforward_sim::scene::SceneFile = toml::from_str(&text).unwrap();
    assert_eq!(back, file);
}
