#![allow(clippy::unwrap_used)]
//! The window path: keyframe selection, and one model pass through grouping to window instances
//! (plumbing, with the reconstruction-contract fixture standing in for a trained model).

use std::path::Path;

use glam::{DQuat, DVec3};
use groupforward::frame::{DepthImage, RgbImage, SyncedFrame};
use groupforward::model::reconstruction::ReconstructionModel;
use groupforward::model::{init_runtime, SessionOptions};
use groupforward::recon::camera::Camera;
use groupforward::recon::Rigid;
use groupforward::window::{window_pass, Keyframes, WindowSection};

fn frame(stamp_secs: f64, x: f64, yaw_deg: f64) -> SyncedFrame {
    let (w, h) = (12, 8);
    SyncedFrame {
        camera_name: "front".into(),
        stamp_nanos: (stamp_secs * 1e9) as i64,
        frame_id: "camera_color_optical_frame".into(),
        rgb: RgbImage {
            width: w,
            height: h,
            data: (0..w * h * 3).map(|i| (i * 7 % 256) as u8).collect(),
        },
        depth: Some(DepthImage {
            width: w,
            height: h,
            metres: (0..w * h).map(|i| 1.0 + (i % 5) as f32 * 0.1).collect(),
        }),
        camera: Camera::from_fov(w, h, 1.2).unwrap(),
        world_from_camera: Rigid::new(
            DQuat::from_rotation_y(yaw_deg.to_radians()),
            DVec3::new(x, 0.0, 0.0),
        ),
    }
}

#[test]
fn keyframes_follow_motion_and_time_and_windows_do_not_overlap() {
    let mut store = Keyframes::new(WindowSection {
        views: 3,
        ..WindowSection::default()
    });
    assert!(
        store.offer(&frame(0.0, 0.0, 0.0)),
        "the first frame is a keyframe"
    );
    assert!(
        !store.offer(&frame(0.1, 0.05, 2.0)),
        "small motion, short time"
    );
    assert!(store.offer(&frame(0.2, 0.25, 2.0)), "moved 0.25 m");
    assert!(store.take_window().is_none(), "two keyframes < three views");
    assert!(store.offer(&frame(0.3, 0.25, 20.0)), "turned 18 degrees");
    let window = store.take_window().unwrap();
    assert_eq!(window.len(), 3);
    assert!(store.take_window().is_none(), "no new keyframes since");
    assert!(store.offer(&frame(1.5, 0.25, 20.0)), "1.2 s passed");
}

#[test]
fn a_window_pass_turns_model_outputs_into_instances_and_views() {
    init_runtime(None).unwrap_or_else(|e| panic!("{e}"));
    let manifest =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/fixtures/recon_contract.toml");
    let mut model = ReconstructionModel::load(&manifest, &SessionOptions::default()).unwrap();
    let frames: Vec<SyncedFrame> = (0..4)
        .map(|i| frame(i as f64 * 0.3, i as f64 * 0.3, 0.0))
        .collect();
    let grouping = groupforward::group::GroupingParams {
        hdbscan: groupforward::group::hdbscan::HdbscanParams {
            min_cluster_size: 10,
            min_samples: 3,
            allow_single_cluster: true,
        },
        ..Default::default()
    };
    let out = window_pass(&mut model, None, &frames, &grouping).unwrap();
    // The fixture works at 6×4: 24 pixel-aligned Gaussians per view.
    assert_eq!(out.gaussians, 4 * 24);
    assert_eq!(out.views.len(), 4);
    assert!(out
        .views
        .iter()
        .all(|v| v.depth.len() == 24 && v.keyframe.camera.width == 6));
    let grouped: usize = out.instances.iter().map(|i| i.gaussians.len()).sum();
    assert_eq!(grouped + out.noise, out.gaussians);
    assert!(!out.instances.is_empty());
    assert!(
        out.instances.iter().all(|i| i.prototype.is_empty()),
        "no semantic model yet"
    );
}
