#![allow(clippy::unwrap_used)]
//! The persistent map: fusion keeps ids, births, decay and death where an instance should have
//! been seen, caps and clearing; the scene graph's attributes; snapshots that survive torn writes.

use glam::{DQuat, DVec3, Quat, Vec3};
use groupforward::frame::{Keyframe, WindowInstance, WindowView};
use groupforward::graph::persist::{self, PersistError};
use groupforward::graph::{FusionParams, SceneMap};
use groupforward::recon::camera::Camera;
use groupforward::recon::gaussians::Gaussians;
use groupforward::recon::Rigid;

/// A solid box of Gaussians on a 2.5 cm grid.
fn cube(center: Vec3, half: f32) -> Gaussians {
    let mut g = Gaussians::with_dims(0, 0);
    let steps = (2.0 * half / 0.025).round() as i32;
    for i in 0..=steps {
        for j in 0..=steps {
            for k in 0..=steps {
                let p =
                    center - Vec3::splat(half) + Vec3::new(i as f32, j as f32, k as f32) * 0.025;
                g.push(
                    p,
                    0.9,
                    Vec3::splat(0.015),
                    Quat::IDENTITY,
                    Vec3::splat(0.5),
                    &[],
                    &[],
                );
            }
        }
    }
    g
}

fn instance(center: Vec3, prototype: [f32; 3]) -> WindowInstance {
    WindowInstance {
        gaussians: cube(center, 0.2),
        prototype: prototype.to_vec(),
        support: 100,
    }
}

/// A 64×48 camera at `eye` looking along +x (world), REP-103 optical frame.
fn keyframe(eye: DVec3, stamp_nanos: i64) -> Keyframe {
    // Optical z → world +x, optical x → world -y, optical y → world -z.
    let rotation = DQuat::from_mat3(&glam::DMat3::from_cols(
        DVec3::new(0.0, -1.0, 0.0),
        DVec3::new(0.0, 0.0, -1.0),
        DVec3::new(1.0, 0.0, 0.0),
    ));
    Keyframe {
        stamp_nanos,
        camera: Camera::from_fov(64, 48, 1.5).unwrap(),
        world_from_camera: Rigid::new(rotation, eye),
    }
}

/// A view whose observed depth is `depth` everywhere.
fn view(eye: DVec3, stamp: i64, depth: f32) -> WindowView {
    WindowView {
        keyframe: keyframe(eye, stamp),
        depth: vec![depth; 64 * 48],
    }
}

const CHAIR: [f32; 3] = [1.0, 0.0, 0.0];
const TABLE: [f32; 3] = [0.0, 1.0, 0.0];

#[test]
fn fusing_overlapping_windows_keeps_ids_and_births_new_objects() {
    let mut map = SceneMap::new(FusionParams::default());
    let eye = DVec3::ZERO;
    let first = map
        .fuse(
            vec![
                instance(Vec3::new(3.0, 0.5, 0.0), CHAIR),
                instance(Vec3::new(3.0, -0.5, 0.0), CHAIR),
            ],
            &[view(eye, 1, 3.0)],
            1,
        )
        .unwrap();
    assert_eq!(first.born, 2);
    // Seen again, slightly shifted (registration noise), listed in the other order, plus a table.
    let second = map
        .fuse(
            vec![
                instance(Vec3::new(3.05, -0.48, 0.0), CHAIR),
                instance(Vec3::new(3.02, 0.52, 0.01), CHAIR),
                instance(Vec3::new(4.0, 0.0, 0.0), TABLE),
            ],
            &[view(eye, 2, 3.0)],
            2,
        )
        .unwrap();
    assert_eq!(second.assigned[0], first.assigned[1]);
    assert_eq!(second.assigned[1], first.assigned[0]);
    assert_eq!((second.merged, second.born), (2, 1));
    assert_eq!(map.instances.len(), 3);
    let chair = &map.instances[0];
    assert_eq!(chair.observations, 2);
    assert!(chair.confidence > FusionParams::default().birth_confidence);
}

#[test]
fn same_place_different_meaning_is_a_new_instance() {
    let mut map = SceneMap::new(FusionParams::default());
    map.fuse(
        vec![instance(Vec3::new(3.0, 0.0, 0.0), CHAIR)],
        &[view(DVec3::ZERO, 1, 3.0)],
        1,
    )
    .unwrap();
    let report = map
        .fuse(
            vec![instance(Vec3::new(3.0, 0.0, 0.0), TABLE)],
            &[view(DVec3::ZERO, 2, 3.0)],
            2,
        )
        .unwrap();
    assert_eq!(report.born, 1);
}

#[test]
fn an_instance_born_without_semantics_takes_the_first_prototype_it_is_merged_with() {
    let mut map = SceneMap::new(FusionParams::default());
    let mut unnamed = instance(Vec3::new(3.0, 0.0, 0.0), CHAIR);
    unnamed.prototype.clear();
    map.fuse(vec![unnamed], &[view(DVec3::ZERO, 1, 3.0)], 1)
        .unwrap();
    assert!(map.instances[0].prototype.is_empty());
    let report = map
        .fuse(
            vec![instance(Vec3::new(3.0, 0.0, 0.0), CHAIR)],
            &[view(DVec3::ZERO, 2, 3.0)],
            2,
        )
        .unwrap();
    assert_eq!((report.merged, report.born), (1, 0));
    assert_eq!(map.instances[0].prototype, CHAIR.to_vec());
    // A later window without semantics keeps what the instance has.
    let mut unnamed = instance(Vec3::new(3.0, 0.0, 0.0), CHAIR);
    unnamed.prototype.clear();
    map.fuse(vec![unnamed], &[view(DVec3::ZERO, 3, 3.0)], 3)
        .unwrap();
    assert_eq!(map.instances[0].prototype, CHAIR.to_vec());
}

#[test]
fn instances_missed_where_visible_decay_and_die_but_occluded_ones_live() {
    let params = FusionParams::default();
    let mut map = SceneMap::new(params);
    map.fuse(
        vec![instance(Vec3::new(3.0, 0.0, 0.0), CHAIR)],
        &[view(DVec3::ZERO, 1, 3.0)],
        1,
    )
    .unwrap();
    // Occluded: the window sees a surface at 1 m, in front of the chair.
    for stamp in 2..6 {
        let report = map
            .fuse(Vec::new(), &[view(DVec3::ZERO, stamp, 1.0)], stamp)
            .unwrap();
        assert_eq!(report.missed, 0);
    }
    assert_eq!(map.instances.len(), 1);
    // Free space: the window sees the wall at 6 m through where the chair was.
    let mut died_at = None;
    for stamp in 6..20 {
        let report = map
            .fuse(Vec::new(), &[view(DVec3::ZERO, stamp, 6.0)], stamp)
            .unwrap();
        assert_eq!(report.missed, usize::from(died_at.is_none()));
        if report.died == 1 {
            died_at = Some(stamp);
        }
        assert!(map.instances.iter().all(|i| i.confidence.is_finite()));
    }
    let expected = 6 + (params.birth_confidence / params.miss_penalty).ceil() as i64 - 1;
    assert_eq!(died_at, Some(expected));
    assert!(map.instances.is_empty());
}

#[test]
fn caps_and_clearing_radius_bound_memory() {
    let params = FusionParams {
        max_gaussians_per_instance: 500,
        max_keyframes: 3,
        clearing_radius: 10.0,
        ..FusionParams::default()
    };
    let mut map = SceneMap::new(params);
    for stamp in 0..5 {
        map.fuse(
            vec![instance(Vec3::new(3.0, 0.0, 0.0), CHAIR)],
            &[view(DVec3::ZERO, stamp, 3.0)],
            stamp,
        )
        .unwrap();
    }
    assert_eq!(map.instances.len(), 1);
    assert!(map.instances[0].gaussians.len() <= 500);
    assert_eq!(map.keyframes.len(), 3);
    // The robot drives 20 m away: the chair is beyond the clearing radius.
    let report = map
        .fuse(Vec::new(), &[view(DVec3::new(-20.0, 0.0, 0.0), 9, 3.0)], 9)
        .unwrap();
    assert_eq!(report.cleared, 1);
    assert!(map.instances.is_empty());
}

#[test]
fn bad_window_instances_are_errors_and_change_nothing() {
    let mut map = SceneMap::new(FusionParams::default());
    map.fuse(
        vec![instance(Vec3::new(3.0, 0.0, 0.0), CHAIR)],
        &[view(DVec3::ZERO, 1, 3.0)],
        1,
    )
    .unwrap();
    let before = map.clone();
    let mut nan = instance(Vec3::new(3.0, 0.0, 0.0), CHAIR);
    nan.gaussians.means[0].x = f32::NAN;
    assert!(map
        .fuse(vec![nan], &[view(DVec3::ZERO, 2, 3.0)], 2)
        .is_err());
    let empty = WindowInstance {
        gaussians: Gaussians::with_dims(0, 0),
        prototype: CHAIR.to_vec(),
        support: 0,
    };
    assert!(map
        .fuse(vec![empty], &[view(DVec3::ZERO, 2, 3.0)], 2)
        .is_err());
    assert_eq!(map, before);
}

#[test]
fn graph_nodes_and_edges_carry_geometry_and_visibility() {
    let mut map = SceneMap::new(FusionParams::default());
    // A chair in front, a table right behind it (hidden), a lamp to the side and higher.
    map.fuse(
        vec![
            instance(Vec3::new(2.0, 0.0, 0.0), CHAIR),
            instance(Vec3::new(3.0, 0.0, 0.0), TABLE),
            instance(Vec3::new(3.0, 1.0, 0.5), [0.0, 0.0, 1.0]),
        ],
        &[view(DVec3::ZERO, 1, 10.0)],
        1,
    )
    .unwrap();
    let graph = map.graph(1, 10.0).unwrap();
    assert_eq!(graph.nodes.len(), 3);
    assert_eq!(graph.edges.len(), 3);
    let (chair, table, lamp) = (&graph.nodes[0], &graph.nodes[1], &graph.nodes[2]);
    assert!(
        chair.views[0].visibility > 0.2,
        "{}",
        chair.views[0].visibility
    );
    assert!(
        table.views[0].visibility < 0.05,
        "hidden behind the chair: {}",
        table.views[0].visibility
    );
    assert!(lamp.views[0].visibility > 0.2);
    let lamp_box = lamp.views[0].bbox.unwrap();
    let chair_box = chair.views[0].bbox.unwrap();
    assert!(lamp_box[2] < chair_box[0] + 1.0, "world +y is image left");
    let edge = graph
        .edges
        .iter()
        .find(|e| e.source == 0 && e.target == 2)
        .unwrap();
    assert!((edge.distance - (1.0f32 + 1.0 + 0.25).sqrt()).abs() < 0.05);
    assert!((edge.height_difference + 0.5).abs() < 0.02);
    assert!((edge.size_ratio - 1.0).abs() < 0.05);
    let seen = edge.views[0];
    assert!(seen.distance.unwrap() > 5.0);
    let direction = seen.direction.unwrap();
    assert!(
        direction.abs() > std::f32::consts::FRAC_PI_2,
        "lamp is left of the chair: {direction}"
    );
}

fn sample_map() -> SceneMap {
    let mut map = SceneMap::new(FusionParams::default());
    map.fuse(
        vec![
            instance(Vec3::new(3.0, 0.5, 0.0), CHAIR),
            instance(Vec3::new(4.0, -0.5, 0.2), TABLE),
        ],
        &[
            view(DVec3::ZERO, 1, 3.0),
            view(DVec3::new(0.5, 0.0, 0.0), 2, 3.0),
        ],
        2,
    )
    .unwrap();
    map
}

#[test]
fn save_then_load_gives_the_identical_map_and_graph() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("map.gfmap");
    let map = sample_map();
    persist::save(&map, &path).unwrap();
    let loaded = persist::load(&path, map.params).unwrap();
    assert_eq!(loaded, map);
    assert_eq!(loaded.graph(2, 10.0).unwrap(), map.graph(2, 10.0).unwrap());
}

#[test]
fn corrupt_truncated_foreign_and_newer_snapshots_are_clear_errors() {
    let bytes = persist::to_bytes(&sample_map());
    let params = FusionParams::default();
    let mut flipped = bytes.clone();
    let middle = flipped.len() / 2;
    flipped[middle] ^= 0x40;
    assert!(matches!(
        persist::from_bytes(&flipped, params),
        Err(PersistError::Corrupt(_))
    ));
    for cut in [0, 5, 20, bytes.len() / 3, bytes.len() - 1] {
        assert!(
            persist::from_bytes(&bytes[..cut], params).is_err(),
            "cut at {cut}"
        );
    }
    assert!(matches!(
        persist::from_bytes(b"PNG not a map at all......", params),
        Err(PersistError::NotAMap)
    ));
    let mut newer = bytes.clone();
    newer[8..12].copy_from_slice(&(persist::VERSION + 1).to_le_bytes());
    assert!(matches!(
        persist::from_bytes(&newer, params),
        Err(PersistError::NewerVersion { found, .. }) if found == persist::VERSION + 1
    ));
}

#[test]
fn a_snapshot_torn_mid_write_never_replaces_the_good_one() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("map.gfmap");
    let good = sample_map();
    persist::save(&good, &path).unwrap();
    let mut bigger = good.clone();
    bigger
        .fuse(
            vec![instance(Vec3::new(6.0, 0.0, 0.0), TABLE)],
            &[view(DVec3::ZERO, 3, 9.0)],
            3,
        )
        .unwrap();
    let bytes = persist::to_bytes(&bigger);
    // The process dies (here: the write fails) halfway through the new snapshot.
    let torn = persist::write_atomically_with(&path, &bytes, |file, bytes| {
        use std::io::Write;
        file.write_all(&bytes[..bytes.len() / 2])?;
        Err(std::io::Error::other("disk full"))
    });
    assert!(torn.is_err());
    assert_eq!(persist::load(&path, good.params).unwrap(), good);
    let leftovers: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(leftovers.len(), 1, "no temp files left behind");
    // And a file torn by a non-atomic writer is detected, not half-loaded.
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    assert!(persist::load(&path, good.params).is_err());
}
