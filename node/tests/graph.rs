#![allow(clippy::unwrap_used)]
//! The persistent map: fusion keeps ids, births, decay and death where an instance should have
//! been seen, caps and clearing; the scene graph's attributes; snapshots that survive torn writes.

use glam::{DQuat, DVec3, Quat, Vec3};
use groupforward::frame::{Keyframe, WindowInstance, WindowView};
use groupforward::graph::persist::{self, PersistError};
use groupforward::graph::{FusionParams, Kinds, SceneMap};
use groupforward::recon::boxes::OrientedBox;
use groupforward::recon::camera::Camera;
use groupforward::recon::gaussians::Gaussians;
use groupforward::recon::Rigid;

/// A solid cube of Gaussians on a 2.5 cm grid.
fn cube(center: Vec3, half: f32) -> Gaussians {
    cuboid(center, Vec3::splat(half))
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
        depth_noise_at_1m: None,
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
fn an_object_the_camera_still_sees_in_place_lives_although_no_window_groups_it() {
    // A thin lamp shade 3 m ahead. Later windows see its surface where it is (depth 2.96 m, its
    // front face) but their grouping gives no instance for it: no evidence that it is gone, so
    // it is not missed. Only free space where it was (the wall at 6 m seen through it) kills it.
    let params = FusionParams::default();
    let mut map = SceneMap::new(params);
    let shade = WindowInstance {
        gaussians: cuboid(Vec3::new(3.0, 0.0, 0.0), Vec3::new(0.04, 0.2, 0.2)),
        prototype: CHAIR.to_vec(),
        support: 50,
    };
    map.fuse(vec![shade], &[view(DVec3::ZERO, 1, 3.0)], 1)
        .unwrap();
    for stamp in 2..10 {
        let report = map
            .fuse(Vec::new(), &[view(DVec3::ZERO, stamp, 2.96)], stamp)
            .unwrap();
        assert_eq!((report.missed, report.died), (0, 0), "window {stamp}");
    }
    assert_eq!(map.instances.len(), 1);
    let mut died = 0;
    for stamp in 10..14 {
        died += map
            .fuse(Vec::new(), &[view(DVec3::ZERO, stamp, 6.0)], stamp)
            .unwrap()
            .died;
    }
    assert_eq!((died, map.instances.len()), (1, 0));
}

#[test]
fn a_far_object_seen_through_depth_noise_lives_but_free_space_beyond_the_noise_kills_it() {
    // A chair 4 m ahead under a depth camera with 6 mm noise at 1 m (σ 9.6 cm there). Windows
    // that do not group it observe depth 15 cm behind its points (about 1.5 σ of the difference
    // of two noisy depths): noise, not free space, once the noise is measured. Without a
    // measurement the fixed 10 cm tolerance counts it as free space and the chair dies.
    let params = FusionParams::default();
    let noisy = |stamp: i64, depth: f32, noise: Option<f32>| WindowView {
        depth_noise_at_1m: noise,
        ..view(DVec3::ZERO, stamp, depth)
    };
    let chair = || WindowInstance {
        gaussians: cuboid(Vec3::new(4.0, 0.0, 0.0), Vec3::new(0.02, 0.2, 0.2)),
        prototype: CHAIR.to_vec(),
        support: 50,
    };
    let surface = 4.0 - 0.02 + 0.15;
    for (noise, survives) in [(Some(0.006), true), (None, false)] {
        let mut map = SceneMap::new(params);
        map.fuse(vec![chair()], &[noisy(1, 3.98, noise)], 1)
            .unwrap();
        let died: usize = (2..8)
            .map(|stamp| {
                map.fuse(Vec::new(), &[noisy(stamp, surface, noise)], stamp)
                    .unwrap()
                    .died
            })
            .sum();
        assert_eq!(map.instances.len() == 1, survives, "noise {noise:?}");
        assert_eq!(died, usize::from(!survives));
    }
    // Far beyond the noise (the wall 2 m behind it) is free space, measured noise or not.
    let mut map = SceneMap::new(params);
    map.fuse(vec![chair()], &[noisy(1, 3.98, Some(0.006))], 1)
        .unwrap();
    for stamp in 2..8 {
        map.fuse(Vec::new(), &[noisy(stamp, 6.0, Some(0.006))], stamp)
            .unwrap();
    }
    assert!(map.instances.is_empty());
}

#[test]
fn a_face_seen_through_range_noise_gets_the_box_of_its_surface_and_a_clean_one_its_points() {
    // A cabinet's front 3 m ahead (0.8 m wide, 1.6 m high, in the plane x = 3), measured three
    // times through 6 mm noise at 1 m: σ 5.4 cm along the view, so its points form a slab
    // ±11 cm deep. The box is fitted to the surface they agree on; without a measured noise
    // (a clean camera) to the points as they are.
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let sigma = 0.006 * 3.0 * 3.0;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let noise = Normal::new(0.0f32, sigma).unwrap();
    let mut face = Gaussians::with_dims(0, 0);
    for _ in 0..3 {
        for i in 0..16 {
            for k in 0..32 {
                let mean = Vec3::new(
                    3.0 + noise.sample(&mut rng),
                    -0.4 + i as f32 * 0.05,
                    k as f32 * 0.05,
                );
                face.push(
                    mean,
                    1.0,
                    Vec3::splat(0.01),
                    Quat::IDENTITY,
                    Vec3::ONE,
                    &[],
                    &[],
                );
            }
        }
    }
    let raw_depth = {
        let xs = face.means.iter().map(|m| m.x);
        xs.clone().fold(f32::NEG_INFINITY, f32::max) - xs.fold(f32::INFINITY, f32::min)
    };
    assert!(raw_depth > 0.3, "{raw_depth}");
    let mut depths = Vec::new();
    for measured in [Some(0.006), None] {
        let mut map = SceneMap::new(FusionParams::default());
        let seen = WindowView {
            depth_noise_at_1m: measured,
            ..view(DVec3::ZERO, 1, 3.0)
        };
        let window = WindowInstance {
            gaussians: face.clone(),
            prototype: CHAIR.to_vec(),
            support: 500,
        };
        map.fuse(vec![window], &[seen], 1).unwrap();
        let instance = &map.instances[0];
        let expected = measured.map_or(0.0, |s| s * 3.0 * 3.0);
        assert!(
            (instance.range_noise_m - expected).abs() < 0.01,
            "{} against {expected}",
            instance.range_noise_m
        );
        let fitted = instance.fitted(true);
        assert_eq!(fitted.points, instance.oriented_box());
        assert_eq!(fitted.surface.is_some(), measured.is_some(), "{fitted:?}");
        for b in [Some(fitted.points), fitted.surface].into_iter().flatten() {
            assert!(b.size.is_finite() && b.centre.is_finite());
            // The face's width and height stay; its depth is what changes.
            let wide = b.size.x.max(b.size.y);
            assert!(wide > 0.7 && b.size.z > 1.4, "{b:?}");
        }
        let thin = |b: &OrientedBox| b.size.x.min(b.size.y);
        depths.push((thin(&fitted.points), fitted.surface.as_ref().map(thin)));
    }
    let (noisy_points, noisy_surface) = depths[0];
    let surface = noisy_surface.unwrap();
    assert!(surface < 0.1, "the surface's box is {surface} m deep");
    assert!(
        noisy_points > 0.18,
        "the points' box is {noisy_points} m deep"
    );
    assert_eq!(depths[1].0, noisy_points, "the points' box needs no noise");
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

/// A solid box of Gaussians on a 2.5 cm grid, `half` its half sizes (multiples of 1.25 cm).
/// A small opaque grey Gaussian at `p`.
fn push_point(g: &mut Gaussians, p: Vec3) {
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

fn cuboid(center: Vec3, half: Vec3) -> Gaussians {
    let mut g = Gaussians::with_dims(0, 0);
    let steps = (2.0 * half / 0.025).round();
    for i in 0..=steps.x as i32 {
        for j in 0..=steps.y as i32 {
            for k in 0..=steps.z as i32 {
                push_point(
                    &mut g,
                    center - half + Vec3::new(i as f32, j as f32, k as f32) * 0.025,
                );
            }
        }
    }
    g
}

#[test]
fn graph_attributes_of_objects_of_different_sizes_match_a_hand_computation() {
    // A 0.4 m cube and a 0.6 x 0.3 x 0.2 m slab farther away, overlapping in the image. A voxel
    // finer than the grid keeps every Gaussian where it was put, so boxes are exact.
    let params = FusionParams {
        voxel: 0.01,
        ..FusionParams::default()
    };
    let mut map = SceneMap::new(params);
    let (cube_center, cube_half) = (Vec3::new(3.0, 0.0, 0.0), Vec3::splat(0.2));
    let (slab_center, slab_half) = (Vec3::new(5.0, 0.3, 0.3), Vec3::new(0.3, 0.15, 0.1));
    let window = [(cube_center, cube_half), (slab_center, slab_half)]
        .into_iter()
        .enumerate()
        .map(|(k, (center, half))| WindowInstance {
            gaussians: cuboid(center, half),
            prototype: if k == 0 {
                CHAIR.to_vec()
            } else {
                TABLE.to_vec()
            },
            support: 100,
        })
        .collect();
    let eye = keyframe(DVec3::ZERO, 1);
    map.fuse(window, &[view(DVec3::ZERO, 1, 10.0)], 1).unwrap();
    let graph = map.graph(1, 10.0).unwrap();
    let (cube, slab) = (&graph.nodes[0], &graph.nodes[1]);
    // Volumes and extents: 0.4^3 = 0.064 and 0.6 * 0.3 * 0.2 = 0.036 m^3.
    assert!((cube.volume - 0.064).abs() < 1e-5, "{}", cube.volume);
    assert!((slab.volume - 0.036).abs() < 1e-5, "{}", slab.volume);
    assert!((Vec3::from_array(slab.extent) - Vec3::new(0.6, 0.3, 0.2)).length() < 1e-5);
    let edge = &graph.edges[0];
    assert_eq!((edge.source, edge.target), (0, 1));
    assert!(
        (edge.size_ratio - 0.064 / 0.036).abs() < 1e-4,
        "{}",
        edge.size_ratio
    );
    assert!((edge.height_difference - -0.3).abs() < 1e-5);
    let expected_distance = (4.0f32 + 0.09 + 0.09).sqrt();
    assert!((edge.distance - expected_distance).abs() < 1e-5);
    // Projected boxes by the pinhole formula on the box corners (optical x = -world y, optical
    // y = -world z, depth = world x): u = cx + f * x / z, v = cy + f * y / z.
    let camera = eye.camera;
    let project_box = |center: Vec3, half: Vec3| {
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for corner in 0..8 {
            let sign = |bit: i32| if corner & bit == 0 { -1.0 } else { 1.0 };
            let p = center + half * Vec3::new(sign(1), sign(2), sign(4));
            let (x, y, z) = (-f64::from(p.y), -f64::from(p.z), f64::from(p.x));
            let (u, v) = (camera.cx + camera.fx * x / z, camera.cy + camera.fy * y / z);
            lo = [lo[0].min(u), lo[1].min(v)];
            hi = [hi[0].max(u), hi[1].max(v)];
        }
        [lo[0], lo[1], hi[0], hi[1]]
    };
    let (a, b) = (
        project_box(cube_center, cube_half),
        project_box(slab_center, slab_half),
    );
    for (node, expected) in [(cube, a), (slab, b)] {
        let bbox = node.views[0].bbox.unwrap();
        for (got, want) in bbox.iter().zip(expected) {
            assert!(
                (f64::from(*got) - want).abs() < 1e-3,
                "{bbox:?} vs {expected:?}"
            );
        }
    }
    let area = |r: [f64; 4]| (r[2] - r[0]) * (r[3] - r[1]);
    let intersection =
        (a[2].min(b[2]) - a[0].max(b[0])).max(0.0) * (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let iou = intersection / (area(a) + area(b) - intersection);
    assert!(iou > 0.05, "the fixture overlaps in the image: {iou}");
    let (dx, dy) = (
        (b[0] + b[2] - a[0] - a[2]) / 2.0,
        (b[1] + b[3] - a[1] - a[3]) / 2.0,
    );
    let seen = edge.views[0];
    assert!((f64::from(seen.overlap.unwrap()) - iou).abs() < 1e-4);
    assert!((f64::from(seen.distance.unwrap()) - dx.hypot(dy)).abs() < 1e-3);
    assert!((f64::from(seen.direction.unwrap()) - dy.atan2(dx)).abs() < 1e-4);
    // Two pixels wide at 5 m in this 64x48 view, the slab lies almost all behind the cube.
    assert!(slab.views[0].visibility < cube.views[0].visibility);
}

#[test]
fn a_window_spanning_two_instances_folds_the_younger_into_the_older() {
    let mut map = SceneMap::new(FusionParams::default());
    // Two parts of one table seen apart (a 10 cm gap: too far to associate), in two windows.
    let first = map
        .fuse(vec![instance(Vec3::new(3.0, 0.0, 0.0), TABLE)], &[], 1)
        .unwrap();
    let second = map
        .fuse(vec![instance(Vec3::new(3.0, 0.5, 0.0), TABLE)], &[], 2)
        .unwrap();
    assert_eq!((first.born, second.born), (1, 1));
    assert_eq!(map.instances.len(), 2);
    let before: usize = map.instances.iter().map(|i| i.gaussians.len()).sum();
    // Then the whole table in one view: both pass the gate, one is matched, the other is a
    // duplicate and folds into the older instance, whichever was matched.
    let whole = WindowInstance {
        gaussians: cuboid(Vec3::new(3.0, 0.25, 0.0), Vec3::new(0.2, 0.45, 0.2)),
        prototype: TABLE.to_vec(),
        support: 300,
    };
    let third = map.fuse(vec![whole], &[], 3).unwrap();
    assert_eq!(
        third.absorbed,
        [("inst_000002".to_owned(), "inst_000001".to_owned())]
    );
    assert_eq!(third.assigned, ["inst_000001"]);
    assert_eq!(map.instances.len(), 1);
    let table = &map.instances[0];
    assert_eq!(table.id, "inst_000001");
    assert_eq!((table.first_seen_nanos, table.last_seen_nanos), (1, 3));
    assert_eq!(table.observations, 3);
    assert!(table.gaussians.len() >= before);
    let (lo, hi) = table.bounds();
    assert!(
        (lo.y - -0.2).abs() < 0.05 && (hi.y - 0.7).abs() < 0.05,
        "{lo} {hi}"
    );
}

#[test]
fn a_part_inside_a_larger_instance_of_the_same_kind_is_folded_even_at_low_box_iou() {
    // One window gives a table and, separately, a piece of the same table: box IoU 0.05, but every
    // point of the piece lies on the table's points.
    let mut map = SceneMap::new(FusionParams::default());
    let table = WindowInstance {
        gaussians: cuboid(Vec3::new(3.0, 0.0, 0.0), Vec3::new(0.5, 0.2, 0.2)),
        prototype: TABLE.to_vec(),
        support: 300,
    };
    let piece = WindowInstance {
        gaussians: cuboid(Vec3::new(3.3, 0.0, 0.0), Vec3::splat(0.1)),
        prototype: TABLE.to_vec(),
        support: 30,
    };
    let report = map.fuse(vec![table, piece], &[], 1).unwrap();
    assert_eq!(
        report.absorbed,
        [("inst_000002".to_owned(), "inst_000001".to_owned())]
    );
    assert_eq!(map.instances.len(), 1);
    // A chair beside the table (a different prototype) is never folded into it.
    let chair = WindowInstance {
        gaussians: cuboid(Vec3::new(3.3, 0.35, 0.0), Vec3::splat(0.15)),
        prototype: CHAIR.to_vec(),
        support: 30,
    };
    map.fuse(vec![chair], &[], 2).unwrap();
    assert_eq!(map.instances.len(), 2);
}

#[test]
fn touching_fragments_named_alike_fold_and_touching_objects_of_two_kinds_do_not() {
    // A bed the window cut in two: its mattress and its headboard touch along a seam, and they
    // share nothing else (box IoU 0), so overlap and parts never fold them.
    let bed = |x: f32, half_x: f32| WindowInstance {
        gaussians: cuboid(Vec3::new(x, 0.0, 0.0), Vec3::new(half_x, 0.5, 0.3)),
        prototype: TABLE.to_vec(),
        support: 300,
    };
    let same_name = |a: &[f32], b: &[f32]| a == b;
    let mut map = SceneMap::new(FusionParams::default());
    let report = map
        .fuse_named(vec![bed(0.0, 0.5), bed(0.6, 0.1)], &[], 1, same_name)
        .unwrap();
    assert_eq!(map.instances.len(), 1, "{:?}", report);
    assert_eq!(
        report.absorbed,
        [("inst_000002".to_owned(), "inst_000001".to_owned())]
    );
    assert_eq!(
        report.assigned,
        ["inst_000001", "inst_000001"],
        "ids follow the fold"
    );
    // Plain fusion keeps them apart (what the fold adds).
    let mut plain = SceneMap::new(FusionParams::default());
    plain
        .fuse(vec![bed(0.0, 0.5), bed(0.6, 0.1)], &[], 1)
        .unwrap();
    assert_eq!(plain.instances.len(), 2);
    // A chair touching the table is another kind: it stays.
    let chair = WindowInstance {
        gaussians: cuboid(Vec3::new(0.75, 0.0, 0.0), Vec3::splat(0.15)),
        prototype: CHAIR.to_vec(),
        support: 100,
    };
    map.fuse_named(vec![chair], &[], 2, same_name).unwrap();
    assert_eq!(map.instances.len(), 2);
    // Two pieces of one kind a metre apart do not touch: two objects.
    let mut apart = SceneMap::new(FusionParams::default());
    apart
        .fuse_named(vec![bed(0.0, 0.5), bed(2.0, 0.3)], &[], 1, same_name)
        .unwrap();
    assert_eq!(apart.instances.len(), 2);
    // Without semantics nothing is "alike": nothing folds.
    let mut unnamed = SceneMap::new(FusionParams::default());
    let bare = |x: f32, half_x: f32| WindowInstance {
        prototype: Vec::new(),
        ..bed(x, half_x)
    };
    unnamed
        .fuse_named(
            vec![bare(0.0, 0.5), bare(0.6, 0.1)],
            &[],
            1,
            |_: &[f32], _: &[f32]| true,
        )
        .unwrap();
    assert_eq!(unnamed.instances.len(), 2);
}

#[test]
fn a_headboard_seen_through_range_noise_folds_into_its_bed_and_an_unmeasured_slab_as_deep_does_not()
{
    // A bed 4-6 m ahead whose middle the window grouping lost: the foot end of its mattress
    // (x 3.1-4.6) and its headboard beyond (x 5.5, 1.9 m wide, rising to 1.2 m), measured through
    // 6 mm noise at 1 m: σ 17 cm at the headboard's range, so its points spread over a metre
    // along the view and its bounds are no back's. With the noise measured, the headboard is
    // judged by where most of its points lie, less the noise's spread, and folds; without a
    // measurement the same metre-deep slab is no back.
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};
    let noise_at_1m = 0.006f32;
    let sigma = noise_at_1m * 5.5 * 5.5;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let along_view = Normal::new(0.0f32, sigma).unwrap();
    let mut headboard = Gaussians::with_dims(0, 0);
    for j in 0..39 {
        for k in 0..15 {
            push_point(
                &mut headboard,
                Vec3::new(
                    5.5 + along_view.sample(&mut rng),
                    -0.95 + j as f32 * 0.05,
                    0.5 + k as f32 * 0.05,
                ),
            );
        }
    }
    let (min_x, max_x) = headboard
        .means
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), p| {
            (lo.min(p.x), hi.max(p.x))
        });
    assert!(
        max_x - min_x > 0.8,
        "the noise spreads it: {}",
        max_x - min_x
    );
    let window = || {
        vec![
            WindowInstance {
                gaussians: cuboid(Vec3::new(3.85, 0.0, 0.24), Vec3::new(0.75, 0.35, 0.24)),
                prototype: TABLE.to_vec(),
                support: 300,
            },
            WindowInstance {
                gaussians: headboard.clone(),
                prototype: TABLE.to_vec(),
                support: 300,
            },
        ]
    };
    let same_name = |a: &[f32], b: &[f32]| a == b;
    for (measured, folds) in [(Some(noise_at_1m), true), (None, false)] {
        let views = [WindowView {
            depth_noise_at_1m: measured,
            ..view(DVec3::ZERO, 1, 5.5)
        }];
        let mut map = SceneMap::new(FusionParams::default());
        let report = map.fuse_named(window(), &views, 1, same_name).unwrap();
        assert_eq!(
            map.instances.len(),
            if folds { 1 } else { 2 },
            "noise {measured:?}: {report:?}"
        );
        assert!(map.instances.iter().all(|i| i.range_noise_m.is_finite()));
    }
}

#[test]
fn a_table_s_legs_fold_into_its_top_whatever_they_are_named_but_a_chair_a_lamp_and_a_bottle_stay() {
    // A table top 0.8 x 0.6 m at 0.72-0.75 m and its four legs, each grouped apart and named
    // "chair" by the semantic model; beside it a chair, a floor lamp's pole (as thin as a leg but
    // outside the top and rising above it) and, standing on the top, a bottle (thin and upright,
    // but above the top).
    let piece = |centre: Vec3, half: Vec3, prototype: [f32; 3]| WindowInstance {
        gaussians: cuboid(centre, half),
        prototype: prototype.to_vec(),
        support: 100,
    };
    let leg_half = Vec3::new(0.025, 0.025, 0.35);
    let legs = [(-0.35, -0.25), (0.35, -0.25), (-0.35, 0.25), (0.35, 0.25)]
        .map(|(x, y)| piece(Vec3::new(x, y, 0.35), leg_half, CHAIR));
    let top = piece(
        Vec3::new(0.0, 0.0, 0.7375),
        Vec3::new(0.4, 0.3, 0.0125),
        TABLE,
    );
    let chair = piece(
        Vec3::new(1.0, 0.0, 0.45),
        Vec3::new(0.225, 0.225, 0.45),
        CHAIR,
    );
    let lamp = piece(
        Vec3::new(-1.0, 0.0, 0.75),
        Vec3::new(0.025, 0.025, 0.75),
        CHAIR,
    );
    let bottle = piece(
        Vec3::new(0.1, 0.0, 0.875),
        Vec3::new(0.025, 0.025, 0.125),
        CHAIR,
    );
    let structure = [0.0, 0.0, 1.0];
    // Named by the first two entries: the third is structure.
    let same_name = |a: &[f32], b: &[f32]| a == b && a != structure;
    let mut map = SceneMap::new(FusionParams::default());
    let mut window = vec![top];
    window.extend(legs);
    window.extend([chair, lamp, bottle]);
    let report = map.fuse_named(window, &[], 1, same_name).unwrap();
    assert_eq!(map.instances.len(), 4, "{report:?}");
    let table = &map.instances[0];
    assert_eq!(table.id, "inst_000001");
    let (lo, hi) = table.bounds();
    assert!(
        lo.z < 0.05 && hi.z > 0.74,
        "the table reaches the floor: {lo} {hi}"
    );
    assert_eq!(report.assigned[..5], ["inst_000001"; 5]);
    // The chair, the lamp and the bottle, each still itself.
    let mut heights: Vec<f32> = map.instances[1..]
        .iter()
        .map(|i| i.bounds().1.z - i.bounds().0.z)
        .collect();
    heights.sort_by(f32::total_cmp);
    for (height, expected) in heights.iter().zip([0.25, 0.9, 1.5]) {
        assert!((height - expected).abs() < 0.03, "{heights:?}");
    }
    // A leg that is structure (a wall's edge the model called "other") does not fold.
    let mut walled = SceneMap::new(FusionParams::default());
    let window = vec![
        piece(
            Vec3::new(0.0, 0.0, 0.7375),
            Vec3::new(0.4, 0.3, 0.0125),
            TABLE,
        ),
        piece(Vec3::new(0.35, 0.25, 0.35), leg_half, structure),
    ];
    walled.fuse_named(window, &[], 1, same_name).unwrap();
    assert_eq!(walled.instances.len(), 2);
}

#[test]
fn overlapping_instances_with_alike_features_but_two_names_are_not_duplicates() {
    // A chair pushed under a table's edge: their boxes overlap and their pooled features are
    // alike (cosine 0.92, above the duplicate threshold), but the vocabulary names one "chair"
    // and the other "table". Without names they fold (what plain `fuse` does); with names they
    // stay two objects, so the chair's id never comes to stand for the table.
    let chair = WindowInstance {
        gaussians: cuboid(Vec3::new(3.0, 0.0, 0.0), Vec3::new(0.25, 0.25, 0.4)),
        prototype: vec![1.0, 0.3, 0.0],
        support: 200,
    };
    let table = WindowInstance {
        gaussians: cuboid(Vec3::new(3.2, 0.1, 0.1), Vec3::new(0.35, 0.3, 0.3)),
        prototype: vec![1.0, 0.0, 0.3],
        support: 300,
    };
    let named = |p: &[f32]| if p[1] > p[2] { "chair" } else { "table" };
    let mut map = SceneMap::new(FusionParams::default());
    let report = map
        .fuse_named(
            vec![chair.clone(), table.clone()],
            &[],
            1,
            |a: &[f32], b: &[f32]| named(a) == named(b),
        )
        .unwrap();
    assert!(report.absorbed.is_empty(), "{:?}", report.absorbed);
    assert_eq!(map.instances.len(), 2);
    let mut plain = SceneMap::new(FusionParams::default());
    let report = plain.fuse(vec![chair, table], &[], 1).unwrap();
    assert_eq!(
        report.absorbed.len(),
        1,
        "the setup overlaps enough to fold"
    );
}

#[test]
fn instances_filling_one_space_are_one_object_whatever_they_are_named() {
    // A trash bin seen as a bin, then again, slightly shifted, with pooled features the
    // vocabulary names "desk": the boxes overlap at IoU ~0.6, which no two solid objects do.
    // The younger folds into the older. A chair and a table at IoU ~0.3 (pushed under its edge)
    // stay two, and neither folds into structure around them.
    let named = |p: &[f32]| if p[1] > p[2] { "bin" } else { "desk" };
    let bin = WindowInstance {
        gaussians: cuboid(Vec3::new(3.0, 0.0, 0.25), Vec3::new(0.15, 0.15, 0.25)),
        prototype: vec![1.0, 0.3, 0.0],
        support: 300,
    };
    let desk = WindowInstance {
        gaussians: cuboid(Vec3::new(3.03, 0.03, 0.22), Vec3::new(0.15, 0.15, 0.22)),
        prototype: vec![0.0, 0.2, 1.0],
        support: 80,
    };
    let mut map = SceneMap::new(FusionParams::default());
    map.fuse_named(vec![bin.clone()], &[], 1, |a: &[f32], b: &[f32]| {
        named(a) == named(b)
    })
    .unwrap();
    let report = map
        .fuse_named(vec![desk.clone()], &[], 2, |a: &[f32], b: &[f32]| {
            named(a) == named(b)
        })
        .unwrap();
    assert_eq!(map.instances.len(), 1, "{report:?}");
    assert_eq!(map.instances[0].id, "inst_000001");
    assert_eq!(
        report.absorbed,
        [("inst_000002".to_owned(), "inst_000001".to_owned())]
    );
    // The window's sighting is reported under the id it went into.
    assert_eq!(report.assigned, ["inst_000001"]);
    // The same pair, the desk one metre away: two objects.
    let mut apart = SceneMap::new(FusionParams::default());
    let mut moved = desk.clone();
    moved.gaussians.means.iter_mut().for_each(|m| m.x += 1.0);
    apart
        .fuse_named(vec![bin.clone(), moved], &[], 1, |a: &[f32], b: &[f32]| {
            named(a) == named(b)
        })
        .unwrap();
    assert_eq!(apart.instances.len(), 2);
    // An object inside structure's space (best name structure: not an object) stays.
    let structure = |p: &[f32]| p[0] > 0.9 && p[1] == 0.0 && p[2] == 0.0;
    let kind = |a: &[f32], b: &[f32]| !structure(a) && !structure(b) && named(a) == named(b);
    let wall = WindowInstance {
        gaussians: cuboid(Vec3::new(3.0, 0.0, 0.25), Vec3::new(0.16, 0.16, 0.26)),
        prototype: vec![1.0, 0.0, 0.0],
        support: 300,
    };
    let mut walled = SceneMap::new(FusionParams::default());
    walled.fuse_named(vec![wall, desk], &[], 1, kind).unwrap();
    assert_eq!(walled.instances.len(), 2);
}

/// A 1 m cabinet standing at (3, 0), named like a table.
fn cabinet() -> WindowInstance {
    WindowInstance {
        gaussians: cuboid(Vec3::new(3.0, 0.0, 0.5), Vec3::splat(0.5)),
        prototype: TABLE.to_vec(),
        support: 300,
    }
}

/// A horizontal slice of [`cabinet`]'s space from `bottom` up, named like a chair.
fn cabinet_part(bottom: f32, height: f32) -> WindowInstance {
    WindowInstance {
        gaussians: cuboid(
            Vec3::new(3.0, 0.0, bottom + height / 2.0),
            Vec3::new(0.5, 0.5, height / 2.0),
        ),
        prototype: CHAIR.to_vec(),
        support: 100,
    }
}

#[test]
fn an_instance_a_fold_grows_is_judged_again_in_the_same_fusion() {
    // A cabinet seen whole, and its lower third seen apart and named "box". A later window sees
    // its middle third, also a "box": it touches the lower third across a 6 cm seam (a fragment:
    // it folds into it), and only together do the two fill the cabinet's space (box IoU 0.32
    // and 0.36 each, about 0.7 together).
    // The grown piece folds into the cabinet in that same fusion, although the cabinet and the
    // piece were both in the map before it and neither was seen by the window.
    let kind = |a: &[f32], b: &[f32]| a == b;
    let mut map = SceneMap::new(FusionParams::default());
    map.fuse_named(vec![cabinet(), cabinet_part(0.0, 0.32)], &[], 1, kind)
        .unwrap();
    assert_eq!(
        map.instances.len(),
        2,
        "a third of the cabinet's space is not all of it"
    );
    let report = map
        .fuse_named(vec![cabinet_part(0.38, 0.36)], &[], 2, kind)
        .unwrap();
    assert_eq!(report.born, 1, "{report:?}");
    assert_eq!(map.instances.len(), 1, "{report:?}");
    assert_eq!(map.instances[0].id, "inst_000001");
    assert_eq!(
        report.absorbed,
        [
            ("inst_000003".to_owned(), "inst_000002".to_owned()),
            ("inst_000002".to_owned(), "inst_000001".to_owned()),
        ]
    );
    assert_eq!(report.assigned, ["inst_000001"], "ids follow both folds");
}

#[test]
fn pieces_that_fold_together_and_then_fill_an_object_s_space_fold_into_it() {
    // The same without a vocabulary, within one rule: a cabinet seen whole, then a window with
    // its lower part and an overlapping middle part (IoU with the cabinet 0.32 and 0.38, under
    // the one-space 0.4). The pair judged first (cabinet, lower part) does not fold; the two
    // parts then fold together (alike, most of the lower one's points on the other), and the
    // grown part fills the cabinet's space (IoU 0.58): it is judged again in the same fusion.
    let mut map = SceneMap::new(FusionParams::default());
    map.fuse(vec![cabinet()], &[], 1).unwrap();
    let report = map
        .fuse(
            vec![cabinet_part(0.0, 0.32), cabinet_part(0.2, 0.38)],
            &[],
            2,
        )
        .unwrap();
    assert_eq!(report.born, 2, "{report:?}");
    assert_eq!(
        report.absorbed,
        [
            ("inst_000003".to_owned(), "inst_000002".to_owned()),
            ("inst_000002".to_owned(), "inst_000001".to_owned()),
        ]
    );
    assert_eq!(map.instances.len(), 1);
    assert_eq!(report.assigned, ["inst_000001", "inst_000001"]);
}

#[test]
fn a_sighting_named_structure_does_not_turn_an_object_into_structure() {
    // A cabinet seen once, then its front seen flat and named structure by a window (its
    // features close enough to the cabinet's to pass association's gate). It stays a cabinet: the
    // structure sighting is its own instance. The other way, a wall piece first, then a sighting
    // named an object at its place, still goes into it.
    let structure = |p: &[f32]| p[2] > p[0];
    let kind = |a: &[f32], b: &[f32]| !structure(a) && !structure(b);
    let cabinet = WindowInstance {
        gaussians: cuboid(Vec3::new(3.0, 0.0, 0.5), Vec3::new(0.25, 0.4, 0.5)),
        prototype: vec![1.0, 0.4, 0.0],
        support: 300,
    };
    let front = WindowInstance {
        gaussians: cuboid(Vec3::new(2.76, 0.0, 0.5), Vec3::new(0.01, 0.4, 0.5)),
        prototype: vec![0.7, 0.4, 0.75],
        support: 300,
    };
    let params = FusionParams::default();
    let similarity = {
        let (a, b) = (&cabinet.prototype, &front.prototype);
        let dot: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
        let norm = |v: &[f32]| v.iter().map(|x| x * x).sum::<f32>().sqrt();
        dot / (norm(a) * norm(b))
    };
    assert!(similarity >= params.min_similarity, "{similarity}");
    let mut map = SceneMap::new(params);
    map.fuse_named(vec![cabinet.clone()], &[], 1, kind).unwrap();
    let report = map.fuse_named(vec![front.clone()], &[], 2, kind).unwrap();
    assert_eq!(report.born, 1, "{report:?}");
    assert_eq!(map.instances.len(), 2);
    assert_eq!(map.instances[0].prototype, cabinet.prototype);
    assert!(!structure(&map.instances[0].prototype));
    let mut walls = SceneMap::new(params);
    walls.fuse_named(vec![front], &[], 1, kind).unwrap();
    let report = walls.fuse_named(vec![cabinet], &[], 2, kind).unwrap();
    assert_eq!((report.merged, walls.instances.len()), (1, 1), "{report:?}");
}

/// Kinds by equal prototypes, with sizes: the first entry above 0.5 is a chair (at most
/// 0.52 m long), anything else a bed (2.34 m).
struct SizedKinds;

impl Kinds for SizedKinds {
    fn same_kind(&self, a: &[f32], b: &[f32]) -> bool {
        a == b
    }

    fn largest_side(&self, prototype: &[f32]) -> Option<f64> {
        Some(if prototype[0] > 0.5 { 0.52 } else { 2.34 })
    }
}

/// One half (1 m) of a bed 2 m long and 1.4 m across, centred at `x`.
fn bed_half(x: f32) -> WindowInstance {
    WindowInstance {
        gaussians: cuboid(Vec3::new(x, 0.0, 0.25), Vec3::new(0.5, 0.7, 0.25)),
        prototype: vec![0.0, 1.0, 0.0],
        support: 400,
    }
}

#[test]
fn two_chairs_side_by_side_stay_two_but_the_halves_of_a_bed_fold() {
    // Two chairs touching, named alike with alike features: fragments by every test but
    // size, and together twice as long as any chair.
    let chair = |x: f32| WindowInstance {
        gaussians: cuboid(Vec3::new(x, 0.0, 0.45), Vec3::new(0.22, 0.22, 0.45)),
        prototype: vec![1.0, 0.0, 0.0],
        support: 200,
    };
    let mut map = SceneMap::new(FusionParams::default());
    let report = map
        .fuse_named(vec![chair(0.0), chair(0.46)], &[], 1, SizedKinds)
        .unwrap();
    assert!(report.absorbed.is_empty(), "{:?}", report.absorbed);
    assert_eq!(map.instances.len(), 2);
    // Without sizes they fold: the setup is a fragment pair.
    let mut without_sizes = SceneMap::new(FusionParams::default());
    let report = without_sizes
        .fuse_named(
            vec![chair(0.0), chair(0.46)],
            &[],
            1,
            |a: &[f32], b: &[f32]| a == b,
        )
        .unwrap();
    assert_eq!(report.absorbed.len(), 1, "{report:?}");
    // A bed's two halves, 2 m together, are one bed.
    let mut bed = SceneMap::new(FusionParams::default());
    let report = bed
        .fuse_named(vec![bed_half(0.0), bed_half(1.02)], &[], 1, SizedKinds)
        .unwrap();
    assert_eq!(report.absorbed.len(), 1, "{report:?}");
    assert_eq!(bed.instances.len(), 1);
}

/// The default vocabulary's bookshelf (first feature) and bed sizes; their typical depths where
/// `depths`.
struct ShelfAndBedKinds {
    depths: bool,
}

impl Kinds for ShelfAndBedKinds {
    fn same_kind(&self, a: &[f32], b: &[f32]) -> bool {
        a == b
    }

    fn largest_side(&self, prototype: &[f32]) -> Option<f64> {
        Some(if prototype[0] > 0.5 { 1.03 } else { 2.34 })
    }

    fn typical_depth(&self, prototype: &[f32]) -> Option<f64> {
        self.depths
            .then_some(if prototype[0] > 0.5 { 0.32 } else { 1.55 })
    }
}

#[test]
fn a_chair_named_like_the_bookshelf_behind_it_is_no_fragment_of_it_but_a_beds_halves_are() {
    // Benchmark 15802: a chair touching a low bookshelf's front, as tall as it, named
    // bookshelf by the features. Together 0.9 m long (no longer than a bookshelf) but 0.8 m
    // deep: 2.5 bookshelves deep.
    let shelf_named = |centre: Vec3, half: Vec3| WindowInstance {
        gaussians: cuboid(centre, half),
        prototype: vec![1.0, 0.0, 0.0],
        support: 300,
    };
    let pair = || {
        vec![
            shelf_named(Vec3::new(0.0, 0.15, 0.45), Vec3::new(0.45, 0.15, 0.45)),
            shelf_named(Vec3::new(0.0, 0.55, 0.45), Vec3::new(0.25, 0.25, 0.45)),
        ]
    };
    let mut map = SceneMap::new(FusionParams::default());
    let report = map
        .fuse_named(pair(), &[], 1, ShelfAndBedKinds { depths: true })
        .unwrap();
    assert!(report.absorbed.is_empty(), "{:?}", report.absorbed);
    assert_eq!(map.instances.len(), 2);
    // Without the depth they fold: the setup is a fragment pair by length.
    let mut by_length = SceneMap::new(FusionParams::default());
    let report = by_length
        .fuse_named(pair(), &[], 1, ShelfAndBedKinds { depths: false })
        .unwrap();
    assert_eq!(report.absorbed.len(), 1, "{report:?}");
    // A bed's two halves, 1.4 m across together (a bed is typically 1.55 m), are one bed.
    let mut bed = SceneMap::new(FusionParams::default());
    let report = bed
        .fuse_named(
            vec![bed_half(0.0), bed_half(1.02)],
            &[],
            1,
            ShelfAndBedKinds { depths: true },
        )
        .unwrap();
    assert_eq!(report.absorbed.len(), 1, "{report:?}");
}

#[test]
fn a_window_that_splits_an_object_puts_every_part_into_its_one_instance() {
    // The map holds a table; the next window gives its top and one leg as two instances (a
    // window's grouping often does). Both parts are that table: no new id, nothing born.
    let mut map = SceneMap::new(FusionParams::default());
    let table = WindowInstance {
        gaussians: cuboid(Vec3::new(3.0, 0.0, 0.0), Vec3::new(0.5, 0.3, 0.2)),
        prototype: TABLE.to_vec(),
        support: 300,
    };
    map.fuse(vec![table], &[], 1).unwrap();
    let top = WindowInstance {
        gaussians: cuboid(Vec3::new(3.0, 0.0, 0.15), Vec3::new(0.5, 0.3, 0.05)),
        prototype: TABLE.to_vec(),
        support: 200,
    };
    let leg = WindowInstance {
        gaussians: cuboid(Vec3::new(3.4, 0.2, -0.05), Vec3::new(0.05, 0.05, 0.15)),
        prototype: TABLE.to_vec(),
        support: 20,
    };
    let report = map.fuse(vec![leg, top], &[], 2).unwrap();
    assert_eq!(report.assigned, ["inst_000001", "inst_000001"]);
    assert_eq!((report.born, report.merged), (0, 2));
    assert!(report.absorbed.is_empty(), "{:?}", report.absorbed);
    assert_eq!(map.instances.len(), 1);
    assert_eq!(map.instances[0].observations, 3);
}

#[test]
fn a_window_instance_spanning_a_chair_and_a_table_folds_neither_into_the_other() {
    // A chair, then a table beside it, each its own instance. A window then groups the two
    // into one instance (its prototype between theirs, close enough to both to pass the gate):
    // the map must not take that for proof that the chair and the table are one object.
    let mut map = SceneMap::new(FusionParams::default());
    let chair = WindowInstance {
        gaussians: cuboid(Vec3::new(3.0, -0.5, 0.0), Vec3::splat(0.2)),
        prototype: CHAIR.to_vec(),
        support: 100,
    };
    map.fuse(vec![chair], &[], 1).unwrap();
    let table = WindowInstance {
        gaussians: cuboid(Vec3::new(3.0, 0.4, 0.0), Vec3::new(0.5, 0.4, 0.2)),
        prototype: TABLE.to_vec(),
        support: 300,
    };
    map.fuse(vec![table], &[], 2).unwrap();
    let both = WindowInstance {
        gaussians: cuboid(Vec3::new(3.0, 0.05, 0.0), Vec3::new(0.5, 0.75, 0.2)),
        prototype: vec![0.6, 0.8, 0.0],
        support: 400,
    };
    let report = map.fuse(vec![both], &[], 3).unwrap();
    assert!(report.absorbed.is_empty(), "{:?}", report.absorbed);
    let ids: Vec<&str> = map.instances.iter().map(|i| i.id.as_str()).collect();
    assert_eq!(ids, ["inst_000001", "inst_000002"]);
}

fn sample_map() -> SceneMap {
    let mut map = SceneMap::new(FusionParams::default());
    map.fuse(
        vec![
            instance(Vec3::new(3.0, 0.5, 0.0), CHAIR),
            instance(Vec3::new(4.0, -0.5, 0.2), TABLE),
        ],
        &[
            WindowView {
                depth_noise_at_1m: Some(0.004),
                ..view(DVec3::ZERO, 1, 3.0)
            },
            view(DVec3::new(0.5, 0.0, 0.0), 2, 3.0),
        ],
        2,
    )
    .unwrap();
    map
}

#[test]
fn the_content_hash_names_a_map_and_changes_with_any_gaussian() {
    let map = sample_map();
    let hash = persist::content_hash(&map);
    assert_eq!(hash.len(), 16);
    assert_eq!(hash, persist::content_hash(&map.clone()));
    let mut moved = map.clone();
    moved.instances[1].gaussians.means[7].x += 1e-3;
    assert_ne!(hash, persist::content_hash(&moved));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("map.gfmap");
    persist::save(&map, &path).unwrap();
    let loaded = persist::load(&path, map.params).unwrap();
    assert_eq!(
        hash,
        persist::content_hash(&loaded),
        "a round trip keeps the hash"
    );
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
    // Where the cameras stood (the mean of the window's two camera centres) travels too: the
    // boxes of objects seen from one side are completed away from it.
    let viewpoint = loaded.instances[0].viewpoint.expect("a viewpoint");
    assert!(
        (viewpoint - Vec3::new(0.25, 0.0, 0.0)).length() < 1e-6,
        "{viewpoint}"
    );
    // So does the range noise it was seen through (the chair's box is fitted to its surface).
    assert!(loaded.instances[0].range_noise_m > 0.01);
    assert_eq!(
        loaded.instances[0].range_noise_m,
        map.instances[0].range_noise_m
    );
    // And where the views saw free space past the instances' ends (a box seen in part grows
    // only where none was seen).
    assert!(map.instances.iter().any(|i| !i.seen_free.is_empty()));
    assert_eq!(loaded.instances[0].seen_free, map.instances[0].seen_free);
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

/// A map with `n` instances of a few hundred Gaussians each: a snapshot of a few hundred kB, so
/// that kills land inside writes, not only between them.
fn map_of(n: usize, prototype: [f32; 3]) -> SceneMap {
    let mut map = SceneMap::new(FusionParams::default());
    let window = (0..n)
        .map(|i| instance(Vec3::new(2.0 * i as f32, 10.0, 0.0), prototype))
        .collect();
    map.fuse(window, &[], 1).unwrap();
    map
}

#[cfg(unix)]
#[test]
fn a_saving_process_killed_at_random_points_always_leaves_a_snapshot_that_loads() {
    const WRITER: &str = "GF_CRASH_WRITER";
    const READY: &str = "GF_CRASH_WRITER_READY";
    let (a, b) = (map_of(12, CHAIR), map_of(20, TABLE));
    // The child: this test, run again with the variable set, saving a and b in turn until killed.
    if let Some(path) = std::env::var_os(WRITER) {
        let path = std::path::PathBuf::from(path);
        // Building the maps takes a dev build tens of milliseconds, more on a loaded machine: the
        // parent's kill clock starts when the saving does, or every kill lands before it.
        if let Some(ready) = std::env::var_os(READY) {
            std::fs::write(ready, b"saving").unwrap();
        }
        loop {
            persist::save(&a, &path).unwrap();
            persist::save(&b, &path).unwrap();
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("map.gfmap");
    persist::save(&a, &path).unwrap();
    let size = std::fs::metadata(&path).unwrap().len();
    assert!(
        size > 100_000,
        "{size} bytes: too small for kills to land mid-write"
    );
    let exe = std::env::current_exe().unwrap();
    let signals = tempfile::tempdir().unwrap();
    let (mut seen_a, mut seen_b, mut mid_write) = (0, 0, 0);
    for trial in 0u64..100 {
        let ready = signals.path().join(format!("ready-{trial}"));
        let mut child = std::process::Command::new(&exe)
            .args([
                "--exact",
                "a_saving_process_killed_at_random_points_always_leaves_a_snapshot_that_loads",
                "--test-threads=1",
            ])
            .env(WRITER, &path)
            .env(READY, &ready)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        let started = std::time::Instant::now();
        while !ready.exists() && started.elapsed() < std::time::Duration::from_secs(30) {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        // A spread of kill times after the saving began (a seeded stride, not wall-clock luck),
        // from inside the first write to many writes in.
        let wait = (trial * 37) % 60;
        std::thread::sleep(std::time::Duration::from_millis(wait));
        child.kill().unwrap(); // SIGKILL: no destructor, no cleanup runs
        child.wait().unwrap();
        // A temp file left behind: this kill landed inside a write.
        mid_write += usize::from(std::fs::read_dir(dir.path()).unwrap().count() > 1);
        let loaded = persist::load(&path, a.params)
            .unwrap_or_else(|e| panic!("trial {trial} (killed after {wait} ms): {e}"));
        if loaded == a {
            seen_a += 1;
        } else if loaded == b {
            seen_b += 1;
        } else {
            panic!("trial {trial}: the snapshot is neither map");
        }
    }
    // The kills landed at different points of the alternating saves.
    assert!(seen_a > 0 && seen_b > 0, "{seen_a} / {seen_b}");
    assert!(
        mid_write > 10,
        "only {mid_write} kills landed inside a write"
    );
    // The next save removes what the killed writers left behind.
    persist::save(&a, &path).unwrap();
    let files: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(files, ["map.gfmap"], "temp files left");
}
