#![allow(clippy::unwrap_used)]
//! Effects: a scene without them is the clean render bit for bit; each one changes only what it
//! claims; everything is deterministic per seed.

use groupforward_sim::effects::Effect;
use groupforward_sim::render::render;
use groupforward_sim::scene::{camera_pose, pinhole, SceneFile};
use groupforward_sim::simulation::{SimFrame, Simulation};

fn base() -> SceneFile {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/two_chairs.toml");
    let mut file = SceneFile::load(&path).unwrap();
    file.cameras[0].width = 64;
    file.cameras[0].height = 48;
    file
}

fn with(effects: Vec<Effect>) -> Simulation {
    let mut file = base();
    file.effects = effects;
    Simulation::new(file).unwrap()
}

fn clean() -> Simulation {
    with(Vec::new())
}

fn frames(sim: &Simulation, n: usize) -> Vec<SimFrame> {
    (0..n).map(|i| sim.frame(i)).collect()
}

#[test]
fn no_effects_is_the_clean_render_bit_for_bit_and_copies_nothing() {
    let sim = clean();
    let file = base();
    let scene = file.build().unwrap();
    let poses = file.robot_poses().unwrap();
    for index in [0, 7, 21] {
        let frame = sim.frame(index);
        let view = &frame.views[0];
        let (rotation, position) = camera_pose(&file.cameras[0], &poses[index]);
        let direct = render(&scene, &pinhole(&file.cameras[0]), rotation, position);
        assert_eq!(view.truth, direct);
        assert!(view.rgb.is_none() && view.depth.is_none(), "no sensor copy");
        assert_eq!(view.sensor_rgb(), &direct.rgb[..]);
        assert_eq!(frame.stamp_secs, frame.time_secs);
        assert_eq!(frame.odometry, frame.robot);
        assert!(!frame.dropped);
        assert_eq!(frame.scene, scene);
    }
}

/// What changed between a frame with effects and the clean frame.
#[derive(Debug, Default, PartialEq)]
struct Changed {
    rgb: bool,
    depth: bool,
    truth: bool,
    stamp: bool,
    odometry: bool,
    dropped: bool,
    objects: bool,
}

fn compare(a: &[SimFrame], b: &[SimFrame]) -> Changed {
    let mut c = Changed::default();
    for (x, y) in a.iter().zip(b) {
        c.dropped |= x.dropped != y.dropped;
        c.stamp |= x.stamp_secs != y.stamp_secs;
        c.odometry |= x.odometry != y.odometry;
        c.objects |= x.scene != y.scene;
        for (v, w) in x.views.iter().zip(&y.views) {
            c.rgb |= v.sensor_rgb() != w.sensor_rgb();
            let bits = |d: &[f32]| d.iter().map(|z| z.to_bits()).collect::<Vec<_>>();
            c.depth |= bits(v.sensor_depth()) != bits(w.sensor_depth());
            c.truth |= v.truth != w.truth;
        }
    }
    c
}

#[test]
fn each_effect_changes_only_what_it_claims() {
    let reference = frames(&clean(), 12);
    let cases: Vec<(Effect, Changed)> = vec![
        (
            Effect::SensorNoise { sigma: 4.0 },
            Changed {
                rgb: true,
                ..Default::default()
            },
        ),
        (
            Effect::MotionBlur {
                exposure_secs: 0.05,
                samples: 3,
            },
            Changed {
                rgb: true,
                ..Default::default()
            },
        ),
        (
            Effect::Exposure {
                min_gain: 0.6,
                max_gain: 1.4,
                period_secs: 1.0,
            },
            Changed {
                rgb: true,
                ..Default::default()
            },
        ),
        (
            Effect::DepthNoise { sigma_at_1m: 0.01 },
            Changed {
                depth: true,
                ..Default::default()
            },
        ),
        (
            Effect::DepthDropout {
                probability: 0.05,
                edge_m: 0.1,
            },
            Changed {
                depth: true,
                ..Default::default()
            },
        ),
        (
            Effect::LensDistortion {
                k1: -0.2,
                k2: 0.05,
                p1: 0.001,
                p2: -0.001,
                k3: 0.0,
            },
            Changed {
                rgb: true,
                depth: true,
                truth: true,
                ..Default::default()
            },
        ),
        (
            Effect::MovingObjects {
                count: 2,
                amplitude_m: 0.2,
                period_secs: 2.0,
            },
            Changed {
                rgb: true,
                depth: true,
                truth: true,
                objects: true,
                ..Default::default()
            },
        ),
        (
            Effect::FrameDrops { probability: 0.3 },
            Changed {
                dropped: true,
                ..Default::default()
            },
        ),
        (
            Effect::TimestampJitter { sigma_secs: 0.01 },
            Changed {
                stamp: true,
                ..Default::default()
            },
        ),
        (
            Effect::OdometryDrift {
                sigma_m: 0.05,
                sigma_yaw_deg: 1.0,
            },
            Changed {
                odometry: true,
                ..Default::default()
            },
        ),
    ];
    for (effect, expected) in cases {
        let sim = with(vec![effect.clone()]);
        let got = frames(&sim, 12);
        let changed = compare(&got, &reference);
        assert_eq!(changed, expected, "{}", effect.kind());
        // Deterministic: the same frames again, in another order.
        let again: Vec<SimFrame> = (0..12).rev().map(|i| sim.frame(i)).collect();
        let again: Vec<SimFrame> = again.into_iter().rev().collect();
        // (Compared bitwise: dropped depth is NaN, which is never equal to itself.)
        assert!(
            compare(&got, &again) == Changed::default(),
            "{} is not deterministic",
            effect.kind()
        );
    }
}

#[test]
fn another_seed_gives_other_noise() {
    let mut a = base();
    a.effects = vec![Effect::SensorNoise { sigma: 4.0 }];
    let mut b = a.clone();
    b.seed = 99;
    let (a, b) = (Simulation::new(a).unwrap(), Simulation::new(b).unwrap());
    assert_ne!(
        a.frame(0).views[0].sensor_rgb(),
        b.frame(0).views[0].sensor_rgb()
    );
}

#[test]
fn depth_dropout_marks_invalid_pixels_and_keeps_the_rest_exact() {
    let sim = with(vec![Effect::DepthDropout {
        probability: 0.1,
        edge_m: 0.2,
    }]);
    let view = &sim.frame(3).views[0];
    let depth = view.sensor_depth();
    let dropped = depth.iter().filter(|z| z.is_nan()).count();
    let n = depth.len();
    assert!(dropped > n / 20 && dropped < n / 2, "{dropped} of {n}");
    for (z, exact) in depth.iter().zip(&view.truth.depth) {
        assert!(z.is_nan() || z == exact);
    }
}

#[test]
fn distorted_ground_truth_reprojects_onto_the_surface_within_a_millimetre() {
    let sim = with(vec![Effect::LensDistortion {
        k1: -0.25,
        k2: 0.06,
        p1: 0.002,
        p2: -0.001,
        k3: 0.0,
    }]);
    let frame = sim.frame(5);
    let view = &frame.views[0];
    let lens = view.distortion.unwrap();
    let cam = view.pinhole;
    let mut checked = 0;
    for v in 0..cam.height as usize {
        for u in 0..cam.width as usize {
            let i = v * cam.width as usize + u;
            let id = view.truth.instance[i];
            if id == 0 {
                continue;
            }
            let (x, y) = lens.undistort((u as f64 - cam.cx) / cam.fx, (v as f64 - cam.cy) / cam.fy);
            // The undistortion is exact: distorting back lands on the pixel.
            let (xd, yd) = lens.distort(x, y);
            assert!((xd * cam.fx + cam.cx - u as f64).abs() < 1e-6);
            assert!((yd * cam.fy + cam.cy - v as f64).abs() < 1e-6);
            let z = f64::from(view.truth.depth[i]);
            let world = view.position + view.rotation * (glam::DVec3::new(x, y, 1.0) * z);
            let object = frame
                .scene
                .objects
                .iter()
                .find(|o| o.instance_id == id)
                .unwrap();
            assert!(object.distance(world).abs() < 1e-3);
            checked += 1;
        }
    }
    assert!(checked > 100);
}

#[test]
fn moving_objects_move_without_touching_anything() {
    let sim = with(vec![Effect::MovingObjects {
        count: 3,
        amplitude_m: 0.3,
        period_secs: 2.0,
    }]);
    assert!(!sim.motions.is_empty());
    for index in 0..sim.frame_count() {
        let scene = sim.scene_at(sim.poses[index].time_secs);
        for (i, a) in scene.objects.iter().enumerate() {
            let (alo, ahi) = a.bounds();
            for b in &scene.objects[i + 1..] {
                if a.support == Some(b.instance_id) || b.support == Some(a.instance_id) {
                    continue;
                }
                let (blo, bhi) = b.bounds();
                let apart = (0..3).any(|k| alo[k] >= bhi[k] - 1e-6 || blo[k] >= ahi[k] - 1e-6);
                assert!(
                    apart,
                    "frame {index}: {} and {} touch",
                    a.instance_id, b.instance_id
                );
            }
        }
    }
}

#[test]
fn a_listed_twice_effect_is_an_error() {
    let mut file = base();
    file.effects = vec![
        Effect::SensorNoise { sigma: 1.0 },
        Effect::SensorNoise { sigma: 2.0 },
    ];
    assert!(Simulation::new(file).is_err());
}

#[test]
fn every_preset_renders_deterministically_and_a_scene_file_can_name_one() {
    use groupforward_sim::effects::Preset;
    for name in [
        "clean",
        "realistic",
        "realistic:depth_noise,depth_dropout",
        "dropout:0.1",
        "dropout:0",
    ] {
        let preset = Preset::parse(name).unwrap();
        let mut file = base();
        file.cameras[0].width = 320;
        file.cameras[0].height = 240;
        file.apply_preset(preset);
        let once = frames(&Simulation::new(file.clone()).unwrap(), 6);
        let twice = frames(&Simulation::new(file).unwrap(), 6);
        assert_eq!(compare(&once, &twice), Changed::default(), "{name}");
        let invalid: usize = once
            .iter()
            .flat_map(|f| &f.views)
            .map(|v| v.sensor_depth().iter().filter(|z| !z.is_finite()).count())
            .sum();
        let pixels: usize = once
            .iter()
            .flat_map(|f| &f.views)
            .map(|v| v.sensor_depth().len())
            .sum();
        let fraction = invalid as f64 / pixels.max(1) as f64;
        match preset {
            Preset::Clean | Preset::Dropout(0.0) => assert_eq!(invalid, 0, "{name}"),
            // 3% random plus the pixels along depth edges.
            Preset::Realistic => assert!((0.03..0.3).contains(&fraction), "{name}: {fraction}"),
            Preset::Dropout(p) => assert!((fraction - p).abs() < 0.02, "{name}: {fraction}"),
            Preset::RealisticOnly(_) => {
                assert!((0.03..0.3).contains(&fraction), "{name}: {fraction}");
                // Only the named two, and the name round-trips.
                let kinds: Vec<&str> = preset.effects().iter().map(Effect::kind).collect();
                assert_eq!(kinds, ["depth_noise", "depth_dropout"]);
                assert_eq!(Preset::parse(&preset.name()), Ok(preset));
            }
        }
    }
    for bad in [
        "",
        "noisy",
        "dropout:",
        "dropout:1.5",
        "dropout:x",
        "realistic:",
        "realistic:fog",
        "realistic:depth_noise,",
    ] {
        assert!(Preset::parse(bad).is_err(), "{bad}");
    }

    // A scene file's preset, with one listed effect replacing the preset's of the same kind.
    let mut file = base();
    file.effects_preset = Some("realistic".into());
    file.effects = vec![Effect::SensorNoise { sigma: 9.0 }];
    let effects = file.resolved_effects().unwrap();
    assert_eq!(effects.len(), Preset::Realistic.effects().len());
    let noise: Vec<_> = effects
        .iter()
        .filter(|e| e.kind() == "sensor_noise")
        .collect();
    assert_eq!(noise, [&Effect::SensorNoise { sigma: 9.0 }]);
    assert!(Simulation::new(file.clone()).is_ok());
    file.effects_preset = Some("fog".into());
    assert!(
        Simulation::new(file).is_err(),
        "an unknown preset is an error"
    );
}
