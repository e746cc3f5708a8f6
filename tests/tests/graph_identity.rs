#![allow(clippy::unwrap_used)]
//! Identity over a sim trajectory: windows built from ground-truth depth and instance masks
//! (standing in for the model until the trained one lands) are fused into the persistent map,
//! which never sees the instance ids. Every object must keep one persistent id from its first
//! sight to its last; identity switches and duplicates are counted and reported.

use std::collections::BTreeMap;

use glam::{Quat, Vec3};
use groupforward::frame::{Keyframe, WindowInstance, WindowView};
use groupforward::graph::{FusionParams, SceneMap};
use groupforward::recon::camera::Camera;
use groupforward::recon::gaussians::Gaussians;
use groupforward::recon::Rigid;
use groupforward_sim::scene::SceneFile;
use groupforward_sim::simulation::Simulation;

/// One-hot class prototype (the semantic model's role), so identical chairs look identical.
fn prototype(class_id: u16) -> Vec<f32> {
    let mut p = vec![0.0; 17];
    p[class_id as usize] = 1.0;
    p
}

/// Run the trajectory; returns (identity switches, persistent ids per object, objects seen).
fn run(file: SceneFile, window_every: usize) -> (usize, BTreeMap<u16, Vec<String>>, usize) {
    let sim = Simulation::new(file).unwrap();
    let mut map = SceneMap::new(FusionParams::default());
    let mut ids: BTreeMap<u16, Vec<String>> = BTreeMap::new();
    for index in (0..sim.frame_count()).step_by(window_every) {
        let frame = sim.frame(index);
        let view = &frame.views[0];
        let c = view.pinhole;
        let camera = Camera::pinhole(c.width, c.height, c.fx, c.fy, c.cx, c.cy).unwrap();
        let world_from_camera = Rigid::new(view.rotation, view.position);
        let mut per_instance: BTreeMap<u16, (Gaussians, u16, usize)> = BTreeMap::new();
        let w = c.width as usize;
        for (i, &id) in view.truth.instance.iter().enumerate() {
            if id == 0 || i % 2 == 1 {
                continue;
            }
            let depth = f64::from(view.truth.depth[i]);
            let pixel = glam::DVec2::new((i % w) as f64, (i / w) as f64);
            let p = world_from_camera.transform_point(camera.unproject(pixel, depth));
            let entry = per_instance
                .entry(id)
                .or_insert_with(|| (Gaussians::with_dims(0, 0), view.truth.class[i], 0));
            entry.0.push(
                p.as_vec3(),
                0.9,
                Vec3::splat(0.01),
                Quat::IDENTITY,
                Vec3::splat(0.5),
                &[],
                &[],
            );
            entry.2 += 1;
        }
        // Slivers at the image border carry too little geometry to identify anything (the model
        // path drops them too: HDBSCAN needs min_cluster_size points of its subsample).
        per_instance.retain(|_, (_, _, pixels)| *pixels >= 60);
        let order: Vec<u16> = per_instance.keys().copied().collect();
        let window = per_instance
            .into_values()
            .map(|(gaussians, class, pixels)| WindowInstance {
                gaussians,
                prototype: prototype(class),
                support: pixels,
            })
            .collect();
        let stamp = (frame.time_secs * 1e9) as i64;
        let views = [WindowView {
            keyframe: Keyframe {
                stamp_nanos: stamp,
                camera,
                world_from_camera,
            },
            depth: view.truth.depth.clone(),
            depth_noise_at_1m: None,
        }];
        let report = map.fuse(window, &views, stamp).unwrap();
        for (gt, persistent) in order.iter().zip(report.assigned) {
            ids.entry(*gt).or_default().push(persistent);
        }
    }
    let switches = ids
        .values()
        .map(|seen| seen.windows(2).filter(|w| w[0] != w[1]).count())
        .sum();
    let seen = ids.len();
    (switches, ids, seen)
}

#[test]
fn every_object_keeps_one_id_along_the_two_chairs_orbit() {
    let mut file = SceneFile::builtin("two_chairs").unwrap();
    file.cameras[0].width = 160;
    file.cameras[0].height = 120;
    let (switches, ids, seen) = run(file, 2);
    eprintln!("two_chairs: {seen} objects, {switches} identity switches: {ids:?}");
    // The lamp never fills 60 sampled pixels at this resolution; the other four objects do.
    assert_eq!(seen, 4);
    assert_eq!(switches, 0, "{ids:?}");
    // No two objects share a persistent id (the identical chairs stay apart).
    let mut firsts: Vec<&String> = ids.values().map(|v| &v[0]).collect();
    firsts.sort();
    firsts.dedup();
    assert_eq!(firsts.len(), seen);
}

#[test]
fn identities_hold_in_procedural_rooms() {
    let mut total_switches = 0;
    let mut total_objects = 0;
    for index in 0..6 {
        let mut file =
            groupforward_sim::procedural::generate(groupforward_sim::procedural::Split::Val, index)
                .unwrap();
        file.cameras[0].width = 128;
        file.cameras[0].height = 96;
        let (switches, ids, seen) = run(file, 3);
        total_switches += switches;
        total_objects += seen;
        // No persistent id ever stands for two objects (a fold of two objects into one would
        // keep every object's own id sequence switch-free and still be wrong).
        let mut objects_of: BTreeMap<&String, Vec<u16>> = BTreeMap::new();
        for (object, persistent) in &ids {
            for id in persistent {
                objects_of.entry(id).or_default().push(*object);
            }
        }
        for (id, objects) in &mut objects_of {
            objects.dedup();
            assert_eq!(objects.len(), 1, "val {index}: {id} is objects {objects:?}");
        }
    }
    eprintln!("procedural val 0..6: {total_objects} objects, {total_switches} identity switches");
    assert!(total_objects >= 20);
    assert_eq!(total_switches, 0, "over {total_objects} objects");
}
