use super::features::FrameKey;
use super::*;
use crate::model::semantic::DenseFeatures;

#[test]
fn each_dropped_point_keeps_the_first_stage_that_dropped_it() {
    let mut why = vec![Unassigned::Noise; 4];
    // HDBSCAN left point 0 as noise; the edge stage dropped point 1, the speck stage 2.
    mark_dropped(&[-1, 0, 0, 1], &[-1, -1, 0, 1], &mut why, Unassigned::Edge);
    mark_dropped(
        &[-1, -1, 0, 1],
        &[-1, -1, -1, 1],
        &mut why,
        Unassigned::Speck,
    );
    assert_eq!(
        why[..3],
        [Unassigned::Noise, Unassigned::Edge, Unassigned::Speck]
    );
    // The codes are negative, distinct, and read back; an instance index is no reason.
    for reason in Unassigned::ALL {
        assert!((reason as i32) < 0);
        assert_eq!(Unassigned::of_code(reason as i32), Some(reason));
    }
    assert_eq!(Unassigned::of_code(0), None);
    assert_eq!(Unassigned::of_code(-7), None);
}

/// A frame `x` metres along the track at `secs` (a keyframe every 0.14 m).
fn frame_at(x: f64, secs: f64) -> SyncedFrame {
    SyncedFrame {
        camera_name: "front".into(),
        stamp_nanos: (secs * 1e9) as i64,
        frame_id: "camera".into(),
        rgb: crate::frame::RgbImage {
            width: 0,
            height: 0,
            data: Vec::new(),
        },
        depth: None,
        camera: crate::recon::camera::Camera::from_fov(4, 4, 1.0).unwrap_or_else(|e| panic!("{e}")),
        world_from_camera: crate::recon::Rigid::new(
            glam::DQuat::IDENTITY,
            glam::DVec3::new(x, 0.0, 0.0),
        ),
    }
}

fn stamps(window: &[SyncedFrame]) -> Vec<i64> {
    window.iter().map(|f| f.stamp_nanos / 100_000_000).collect()
}

#[test]
fn keyframes_short_of_a_window_when_the_stream_ends_form_one_with_the_newest() {
    let mut store = Keyframes::new(WindowSection {
        views: 4,
        exposure_compensation: false,
        ..WindowSection::default()
    });
    // Three keyframes: fewer than a model pass takes, so nothing even at the end.
    for k in 0..3 {
        assert!(store.offer(&frame_at(0.3 * f64::from(k), 0.1 * f64::from(k))));
    }
    assert_eq!(store.take_pending_window(), None);
    // The fourth completes a window; two more wait for the next one.
    assert!(store.offer(&frame_at(0.9, 0.3)));
    assert_eq!(
        store.take_window().as_deref().map(stamps),
        Some(vec![0, 1, 2, 3])
    );
    assert_eq!(store.take_pending_window(), None, "nothing waits");
    for k in 4..6 {
        assert!(store.offer(&frame_at(0.3 * f64::from(k), 0.1 * f64::from(k))));
    }
    assert_eq!(store.take_window(), None);
    assert_eq!(
        store.take_pending_window().as_deref().map(stamps),
        Some(vec![2, 3, 4, 5]),
        "the newest four, two of them already in the last window"
    );
    assert_eq!(store.take_pending_window(), None, "taken once");
}

#[test]
fn a_camera_turning_sixty_degrees_a_second_keeps_every_other_frame() {
    // A walk that looks around turns this fast (the simulator's heading changes 6 degrees a frame
    // at 10 Hz, one standard deviation). At 15 degrees a keyframe (the old default) two frames in
    // three were skipped, and what the camera glimpsed only in them was never mapped.
    let mut store = Keyframes::new(WindowSection {
        exposure_compensation: false,
        ..WindowSection::default()
    });
    let kept: Vec<bool> = (0..12)
        .map(|k| {
            let mut frame = frame_at(0.0, 0.1 * f64::from(k));
            frame.world_from_camera.rotation =
                glam::DQuat::from_rotation_z(f64::from(6 * k).to_radians());
            store.offer(&frame)
        })
        .collect();
    let every_other: Vec<bool> = (0..12).map(|k| k % 2 == 0).collect();
    assert_eq!(kept, every_other);
}

#[test]
fn a_quiet_stream_flushes_its_waiting_keyframes_only_after_the_configured_time() {
    let started = std::time::Instant::now();
    for (flush_after_secs, expected) in [(1.0, true), (0.0, false)] {
        let mut store = Keyframes::new(WindowSection {
            views: 2,
            exposure_compensation: false,
            flush_after_secs,
            ..WindowSection::default()
        });
        for k in 0..3 {
            store.offer(&frame_at(0.3 * f64::from(k), 0.1 * f64::from(k)));
        }
        assert!(store.take_window().is_some());
        store.offer(&frame_at(0.9, 0.3));
        assert_eq!(store.take_quiet_window(started), None, "not quiet yet");
        let later = std::time::Instant::now() + std::time::Duration::from_secs(2);
        assert_eq!(
            store.take_quiet_window(later).is_some(),
            expected,
            "flush_after_secs {flush_after_secs}"
        );
    }
}

fn features(value: f32) -> KeyframeFeatures {
    let dense = DenseFeatures {
        width: 1,
        height: 1,
        channels: 1,
        data: vec![value],
    };
    KeyframeFeatures::named(dense, None)
}

fn key(camera: &str, stamp: i64) -> FrameKey {
    (camera.to_owned(), stamp)
}

#[test]
fn each_point_takes_the_class_of_the_feature_pixel_it_falls_in() {
    // One view of 4 x 2 model pixels, features of 2 x 1 pixels in 2 channels: the left
    // feature pixel points at "chair", the right one at "table".
    let features = DenseFeatures {
        width: 2,
        height: 1,
        channels: 2,
        data: vec![1.0, 0.1, 0.1, 1.0],
    };
    let vocabulary = Vocabulary {
        phrases: vec!["chair".into(), "table".into()],
        embeddings: vec![vec![1.0, 0.0], vec![0.0, 1.0]],
        temperature: 0.05,
        priors: crate::group::semantics::ClassPriors::builtin(),
    };
    let named = KeyframeFeatures::named(features.clone(), Some(&vocabulary));
    let classes = point_classes(&[named], &[0, 1, 2, 7, 99], (4, 2));
    assert_eq!(classes, [Some(0), Some(0), Some(1), Some(1), None]);
    // Features no vocabulary named have no classes.
    let unnamed = KeyframeFeatures::named(features, None);
    assert_eq!(point_classes(&[unnamed], &[0, 7], (4, 2)), [None, None]);
}

#[test]
fn feature_classes_are_each_pixels_best_phrase_by_cosine() {
    // 5 x 3 pixels of 6 channels against phrases of every length and norm: the GEMM's
    // classes equal a plain per-pixel cosine argmax; a phrase of the wrong width or of zero
    // length is never chosen, and a pixel with a NaN feature has no class.
    let (width, height, channels) = (5, 3, 6);
    let plane = width * height;
    let mut data: Vec<f32> = (0..channels * plane)
        .map(|i| ((i * 7919) % 113) as f32 / 56.0 - 1.0)
        .collect();
    data[2 * plane + 4] = f32::NAN;
    let f = DenseFeatures {
        width,
        height,
        channels,
        data,
    };
    let embeddings: Vec<Vec<f32>> = vec![
        vec![1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        vec![0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        vec![0.2, -1.0, 0.5, 0.0, 3.0, 0.1],
        vec![5.0, 5.0],
        vec![0.0, 2.0, 0.0, -1.0, 0.0, 0.7],
    ];
    let vocabulary = Vocabulary {
        phrases: (0..embeddings.len()).map(|k| format!("p{k}")).collect(),
        embeddings: embeddings.clone(),
        temperature: 0.05,
        priors: crate::group::semantics::ClassPriors::builtin(),
    };
    let classes = feature_classes(&f, &vocabulary);
    assert_eq!(classes.len(), plane);
    for (p, class) in classes.iter().enumerate() {
        let pixel: Vec<f32> = (0..channels).map(|c| f.data[c * plane + p]).collect();
        let mut best: Option<(u32, f32)> = None;
        for (k, e) in embeddings.iter().enumerate() {
            let norm = e.iter().map(|v| v * v).sum::<f32>().sqrt();
            if e.len() != channels || norm == 0.0 {
                continue;
            }
            let cosine = e.iter().zip(&pixel).map(|(a, b)| a * b).sum::<f32>() / norm;
            if cosine.is_finite() && best.is_none_or(|(_, s)| cosine > s) {
                best = Some((k as u32, cosine));
            }
        }
        assert_eq!(*class, best.map(|(k, _)| k), "pixel {p}");
    }
    assert_eq!(classes[4], None, "the NaN pixel");
    assert!(classes.iter().flatten().all(|&k| k != 1 && k != 3));
}

#[test]
fn the_feature_cache_keeps_the_newest_entries_and_hands_each_out_once() {
    let mut cache = FeatureCache::with_capacity(2);
    cache.insert(key("front", 1), features(1.0));
    cache.insert(key("front", 2), features(2.0));
    // A second insert of a key keeps the first features.
    cache.insert(key("front", 2), features(9.0));
    cache.insert(key("front", 3), features(3.0));
    assert_eq!(cache.len(), 2, "capacity bounds the entries");
    assert!(cache.take(&key("front", 1)).is_none(), "the oldest left");
    assert_eq!(cache.take(&key("front", 2)), Some(features(2.0)));
    assert!(cache.take(&key("front", 2)).is_none(), "handed out once");
    assert!(
        cache.take(&key("rear", 3)).is_none(),
        "another camera's stamp"
    );
    assert_eq!(cache.take(&key("front", 3)), Some(features(3.0)));
    assert!(cache.is_empty());
    let mut off = FeatureCache::with_capacity(0);
    off.insert(key("front", 1), features(1.0));
    assert!(off.is_empty());
}
