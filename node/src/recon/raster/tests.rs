use super::*;
use glam::{DQuat, Quat, Vec3};
use proptest::prelude::*;

/// A small deterministic pseudo-random generator, so scenes need no extra dependency.
struct Lcg(u64);

impl Lcg {
    fn next(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32) / (1u64 << 24) as f32
    }

    fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next()
    }
}

fn camera() -> Camera {
    Camera::pinhole(48, 36, 40.0, 42.0, 23.5, 17.0).unwrap()
}

/// `n` Gaussians in front of a camera at the origin looking down +z, with `c` channels.
fn scene(seed: u64, n: usize, c: usize) -> (Gaussians, Vec<f32>) {
    let mut rng = Lcg(seed);
    let mut g = Gaussians::with_dims(0, 0);
    let mut features = Vec::new();
    for _ in 0..n {
        let z = rng.range(1.0, 6.0);
        let mean = Vec3::new(rng.range(-0.7, 0.7) * z, rng.range(-0.5, 0.5) * z, z);
        let scale = Vec3::new(
            rng.range(0.01, 0.3),
            rng.range(0.01, 0.3),
            rng.range(0.001, 0.2),
        );
        let rotation = Quat::from_xyzw(
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
            rng.range(-1.0, 1.0),
        );
        g.push(
            mean,
            rng.range(0.05, 1.0),
            scale,
            rotation,
            Vec3::ONE,
            &[],
            &[],
        );
        features.extend((0..c).map(|_| rng.next()));
    }
    (g, features)
}

fn pose() -> Rigid {
    Rigid::IDENTITY
}

fn relative_error(fast: &[f32], reference: &[f32]) -> f64 {
    let max_ref = reference
        .iter()
        .fold(0.0f64, |m, v| m.max(f64::from(v.abs())));
    let max_diff = fast
        .iter()
        .zip(reference)
        .fold(0.0f64, |m, (a, b)| m.max(f64::from((a - b).abs())));
    max_diff / max_ref.max(1e-12)
}

fn assert_valid(r: &Render) {
    assert!(r.features.iter().all(|v| v.is_finite()));
    assert!(r.alpha.iter().all(|a| (0.0..=1.0).contains(a)));
    assert!(r
        .depth
        .iter()
        .zip(&r.alpha)
        .all(|(d, a)| d.is_finite() && *d >= 0.0 && (*a == 0.0 || *d > 0.0)));
}

#[test]
fn tile_renderer_matches_brute_force_reference_on_random_scenes() {
    for (seed, n, c) in [(1, 40, 3), (2, 150, 8), (3, 300, 4), (4, 5, 1)] {
        let (g, features) = scene(seed, n, c);
        let settings = RasterSettings::default();
        let fast = render(&g, &features, c, &camera(), &pose(), &settings).unwrap();
        let slow = reference::render(&g, &features, c, &camera(), &pose(), &settings).unwrap();
        let errors = [
            relative_error(&fast.features, &slow.features),
            relative_error(&fast.alpha, &slow.alpha),
            relative_error(&fast.depth, &slow.depth),
        ];
        assert!(
            errors.iter().all(|e| *e <= 1e-4),
            "seed {seed}: relative errors {errors:?}"
        );
        assert!(
            fast.alpha.iter().any(|a| *a > 0.5),
            "seed {seed}: scene should cover pixels"
        );
        assert_valid(&fast);
    }
}

#[test]
fn label_render_picks_the_label_a_one_hot_channel_render_picks() {
    for (seed, n, labels) in [(11, 60, 3), (12, 200, 9), (13, 400, 30)] {
        let (g, _) = scene(seed, n, 0);
        let label_of: Vec<u32> = (0..n).map(|i| (i * 7 % labels) as u32).collect();
        let one_hot: Vec<f32> = label_of
            .iter()
            .flat_map(|&l| (0..labels).map(move |k| if k == l as usize { 1.0 } else { 0.0 }))
            .collect();
        let settings = RasterSettings::default();
        let channels = render(&g, &one_hot, labels, &camera(), &pose(), &settings).unwrap();
        let fast = render_labels(&g, &label_of, &camera(), &pose(), &settings).unwrap();
        assert_eq!(fast.alpha, channels.alpha, "seed {seed}");
        assert_eq!(fast.depth, channels.depth, "seed {seed}");
        let mut compared = 0;
        for p in 0..fast.labels.len() {
            let weights = &channels.features[p * labels..(p + 1) * labels];
            let best = weights.iter().cloned().fold(0.0f32, f32::max);
            if best <= 0.0 {
                assert_eq!(fast.labels[p], None, "seed {seed} pixel {p}");
                continue;
            }
            // Where two labels tie to rounding, either is right.
            let chosen = fast.labels[p].expect("a rendered pixel has a label") as usize;
            assert!(
                weights[chosen] >= best * (1.0 - 1e-5),
                "seed {seed} pixel {p}: {weights:?} chose {chosen}"
            );
            compared += 1;
        }
        assert!(compared > 100, "seed {seed}: {compared} pixels");
    }
    let (g, _) = scene(1, 10, 0);
    assert!(render_labels(&g, &[0; 9], &camera(), &pose(), &RasterSettings::default()).is_err());
}

#[test]
fn the_comparison_is_sensitive_to_a_small_change() {
    // A 3% different low-pass filter is far outside the tolerance: the check above has teeth.
    let (g, features) = scene(1, 40, 3);
    let fast = render(
        &g,
        &features,
        3,
        &camera(),
        &pose(),
        &RasterSettings::default(),
    )
    .unwrap();
    let other = RasterSettings {
        low_pass: 0.31,
        ..RasterSettings::default()
    };
    let slow = reference::render(&g, &features, 3, &camera(), &pose(), &other).unwrap();
    assert!(relative_error(&fast.features, &slow.features) > 1e-3);
}

#[test]
fn odd_tile_sizes_and_rotated_cameras_match_the_reference() {
    let (g, features) = scene(7, 120, 3);
    let settings = RasterSettings {
        tile_size: 7,
        ..RasterSettings::default()
    };
    let camera_from_world = Rigid::new(
        DQuat::from_rotation_y(0.2) * DQuat::from_rotation_z(0.4),
        glam::DVec3::new(0.1, -0.2, 0.5),
    );
    let fast = render(&g, &features, 3, &camera(), &camera_from_world, &settings).unwrap();
    let slow =
        reference::render(&g, &features, 3, &camera(), &camera_from_world, &settings).unwrap();
    assert!(relative_error(&fast.features, &slow.features) <= 1e-4);
}

#[test]
fn rendering_is_deterministic_across_thread_counts() {
    let (g, features) = scene(11, 400, 5);
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                render(
                    &g,
                    &features,
                    5,
                    &camera(),
                    &pose(),
                    &RasterSettings::default(),
                )
                .unwrap()
            })
    };
    assert_eq!(run(1), run(2));
    assert_eq!(run(2), run(3));
}

fn single(mean: Vec3, opacity: f32, scale: Vec3, rotation: Quat) -> Render {
    let mut g = Gaussians::with_dims(0, 0);
    g.push(mean, opacity, scale, rotation, Vec3::ONE, &[], &[]);
    let r = render(
        &g,
        &[1.0],
        1,
        &camera(),
        &pose(),
        &RasterSettings::default(),
    )
    .unwrap();
    assert_valid(&r);
    let slow = reference::render(
        &g,
        &[1.0],
        1,
        &camera(),
        &pose(),
        &RasterSettings::default(),
    )
    .unwrap();
    assert!(relative_error(&r.alpha, &slow.alpha) <= 1e-4 || slow.alpha.iter().all(|a| *a == 0.0));
    r
}

fn covered(r: &Render) -> usize {
    r.alpha.iter().filter(|a| **a > 0.0).count()
}

#[test]
fn degenerate_scales_stay_finite() {
    let centre = Vec3::new(0.0, 0.0, 2.0);
    for scale in [
        Vec3::ZERO,
        Vec3::splat(-0.1),
        Vec3::splat(1e-9),
        Vec3::splat(1e6),
        Vec3::new(0.5, 0.5, 0.0),
    ] {
        let r = single(centre, 0.9, scale, Quat::IDENTITY);
        assert!(covered(&r) > 0, "scale {scale} renders something");
    }
    // Zero scale is the low-pass footprint: a few pixels, not nothing and not everything.
    assert!(covered(&single(centre, 0.9, Vec3::ZERO, Quat::IDENTITY)) < 30);
    // Negative scales are their absolute values.
    assert_eq!(
        single(centre, 0.9, Vec3::splat(-0.1), Quat::IDENTITY),
        single(centre, 0.9, Vec3::splat(0.1), Quat::IDENTITY)
    );
}

#[test]
fn near_singular_projected_covariances_stay_invertible() {
    // A needle across the view projects to a line, one along the view to a point: without the
    // low-pass both 2D covariances are singular.
    let centre = Vec3::new(0.0, 0.0, 2.0);
    let across = single(centre, 0.9, Vec3::new(0.5, 1e-9, 1e-9), Quat::IDENTITY);
    let along = single(centre, 0.9, Vec3::new(1e-9, 1e-9, 0.5), Quat::IDENTITY);
    assert!(covered(&across) > covered(&along));
    let row = 17 * 48;
    // 14 px from the centre is ~1.4σ of the needle's 10 px: alpha 0.9·e^(-1) ≈ 0.33.
    assert!(
        across.alpha[row + 10] > 0.25 && across.alpha[row + 38] > 0.25,
        "the line spans the view"
    );
    assert!(across.alpha[row - 48 * 5 + 24] < 0.05, "and is thin");
    assert!(covered(&along) < 30, "a point-like footprint");
}

#[test]
fn zero_and_non_unit_quaternions_are_handled() {
    let centre = Vec3::new(0.1, 0.0, 2.0);
    let scale = Vec3::new(0.3, 0.05, 0.05);
    let zero = single(centre, 0.8, scale, Quat::from_xyzw(0.0, 0.0, 0.0, 0.0));
    let identity = single(centre, 0.8, scale, Quat::IDENTITY);
    assert_eq!(zero, identity);
    let scaled = single(centre, 0.8, scale, Quat::from_xyzw(0.0, 0.0, 3.0, 3.0));
    let unit = single(
        centre,
        0.8,
        scale,
        Quat::from_xyzw(0.0, 0.0, 1.0, 1.0).normalize(),
    );
    assert_eq!(scaled, unit);
}

#[test]
fn gaussians_behind_on_and_far_from_the_near_plane() {
    let scale = Vec3::splat(0.1);
    assert_eq!(
        covered(&single(
            Vec3::new(0.0, 0.0, -1.0),
            1.0,
            scale,
            Quat::IDENTITY
        )),
        0
    );
    assert_eq!(
        covered(&single(
            Vec3::new(0.0, 0.0, DEFAULT_NEAR as f32),
            1.0,
            scale,
            Quat::IDENTITY
        )),
        0
    );
    assert_eq!(
        covered(&single(
            Vec3::new(0.0, 0.0, 1e-6),
            1.0,
            scale,
            Quat::IDENTITY
        )),
        0
    );
    let far = single(Vec3::new(0.0, 0.0, 1e6), 1.0, scale, Quat::IDENTITY);
    assert!(covered(&far) > 0 && covered(&far) < 30);
    let at = 17 * 48 + 24;
    assert!((far.depth[at] - 1e6).abs() / 1e6 < 1e-5);
}

#[test]
fn opacity_zero_and_one() {
    let centre = Vec3::new(0.0, 0.0, 2.0);
    assert_eq!(
        covered(&single(centre, 0.0, Vec3::splat(0.2), Quat::IDENTITY)),
        0
    );
    let opaque = single(centre, 1.0, Vec3::splat(0.2), Quat::IDENTITY);
    // Alpha is capped at 0.99 per Gaussian.
    assert!(opaque.alpha.iter().all(|a| *a <= 0.99 + 1e-6));
    assert!(opaque.alpha.iter().any(|a| *a > 0.98));
}

#[test]
fn centres_on_tile_borders_and_whole_image_gaussians() {
    // Pixel (16, 16) is a tile corner: its pixel and its neighbours across the border all see it.
    let camera = camera();
    let z = 2.0;
    let on_border = Vec3::new(
        ((16.0 - camera.cx) / camera.fx * z) as f32,
        ((16.0 - camera.cy) / camera.fy * z) as f32,
        z as f32,
    );
    let r = single(on_border, 0.9, Vec3::splat(0.02), Quat::IDENTITY);
    let at = |x: usize, y: usize| r.alpha[y * 48 + x];
    assert!(at(16, 16) > 0.5 && (at(15, 15) - at(17, 17)).abs() < 1e-3 && at(15, 16) > 0.0);
    let whole = single(
        Vec3::new(0.0, 0.0, 1.0),
        0.9,
        Vec3::splat(50.0),
        Quat::IDENTITY,
    );
    assert_eq!(covered(&whole), 48 * 36);
}

#[test]
fn empty_scenes_render_nothing_and_bad_inputs_are_errors() {
    let empty = render(
        &Gaussians::default(),
        &[],
        4,
        &camera(),
        &pose(),
        &RasterSettings::default(),
    )
    .unwrap();
    assert!(empty.alpha.iter().all(|a| *a == 0.0) && empty.features.iter().all(|f| *f == 0.0));
    let (mut g, features) = scene(5, 3, 2);
    assert!(matches!(
        render(
            &g,
            &features[..5],
            2,
            &camera(),
            &pose(),
            &RasterSettings::default()
        ),
        Err(RasterError::FeatureLength { .. })
    ));
    let mut nan_features = features.clone();
    nan_features[1] = f32::NAN;
    assert!(matches!(
        render(
            &g,
            &nan_features,
            2,
            &camera(),
            &pose(),
            &RasterSettings::default()
        ),
        Err(RasterError::NonFiniteFeature(1))
    ));
    let bad_pose = Rigid::new(DQuat::IDENTITY, glam::DVec3::new(f64::INFINITY, 0.0, 0.0));
    assert!(matches!(
        render(
            &g,
            &features,
            2,
            &camera(),
            &bad_pose,
            &RasterSettings::default()
        ),
        Err(RasterError::BadPose)
    ));
    g.means[0].x = f32::NAN;
    assert!(matches!(
        render(
            &g,
            &features,
            2,
            &camera(),
            &pose(),
            &RasterSettings::default()
        ),
        Err(RasterError::Gaussians(_))
    ));
}

#[test]
fn rendered_probabilities_sum_to_at_most_one() {
    let (g, _) = scene(9, 200, 0);
    let k = 4;
    let mut rng = Lcg(3);
    let mut probabilities = Vec::new();
    for _ in 0..g.len() {
        let raw: Vec<f32> = (0..k).map(|_| rng.next()).collect();
        let sum: f32 = raw.iter().sum();
        probabilities.extend(raw.iter().map(|v| v / sum));
    }
    let r = render(
        &g,
        &probabilities,
        k,
        &camera(),
        &pose(),
        &RasterSettings::default(),
    )
    .unwrap();
    for (pixel, alpha) in r.alpha.iter().enumerate() {
        let sum: f32 = r.features[pixel * k..(pixel + 1) * k].iter().sum();
        assert!(sum <= 1.0 + 1e-5 && (sum - alpha).abs() < 1e-4);
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn any_finite_gaussians_render_finite_and_in_range(
        means in prop::collection::vec((-5f32..5.0, -5f32..5.0, -2f32..1e3), 0..20),
        scales in prop::collection::vec((-1e3f32..1e3, 0f32..1e-3, 0f32..1e6), 20),
        opacities in prop::collection::vec(-0.5f32..1.5, 20),
        quats in prop::collection::vec((-1f32..1.0, -1f32..1.0, -1f32..1.0, -1f32..1.0), 20),
    ) {
        let mut g = Gaussians::with_dims(0, 0);
        for (i, m) in means.iter().enumerate() {
            let s = scales[i];
            let q = quats[i];
            g.push(Vec3::new(m.0, m.1, m.2), opacities[i], Vec3::new(s.0, s.1, s.2), Quat::from_xyzw(q.0, q.1, q.2, q.3), Vec3::ONE, &[], &[]);
        }
        let features = vec![0.5; g.len() * 2];
        let r = render(&g, &features, 2, &camera(), &pose(), &RasterSettings::default()).unwrap();
        assert_valid(&r);
    }

    #[test]
    fn result_does_not_depend_on_gaussian_order(seed in 0u64..1000, rotate in 1usize..30) {
        let (g, features) = scene(seed, 30, 2);
        let order: Vec<usize> = (0..30).map(|i| (i + rotate) % 30).collect();
        let mut shuffled = Gaussians::with_dims(0, 0);
        let mut shuffled_features = Vec::new();
        for &i in &order {
            shuffled.push(g.means[i], g.opacities[i], g.scales[i], g.rotations[i], g.colors[i], &[], &[]);
            shuffled_features.extend_from_slice(&features[i * 2..i * 2 + 2]);
        }
        let a = render(&g, &features, 2, &camera(), &pose(), &RasterSettings::default()).unwrap();
        let b = render(&shuffled, &shuffled_features, 2, &camera(), &pose(), &RasterSettings::default()).unwrap();
        prop_assert_eq!(a, b);
    }
}
