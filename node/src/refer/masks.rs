//! Masks at the camera's own resolution, cut by the depth it measured: a pixel belongs to the
//! answer where the point its depth measured lies on the answer's map points (the nearest map
//! point within a voxel and the sensor's noise is one of theirs), so the outline is the
//! sensor's, not the splats'. A pixel without a depth reading, and a view without depth, get the
//! answer's splats rendered there ([`label_image`]), cut by the map's rendered depth so occluded
//! parts stay out.

use std::ops::Range;

use glam::{DVec2, Vec3};

use super::scene::{pixels, resampled, ReferScene, MASK_ALPHA};
use crate::frame::{world_points, Keyframe, MeasuredDepth};
use crate::recon::gaussians::Gaussians;
use crate::recon::raster::{render_labels, RasterSettings};

/// A measured point is an instance's when one of its map points lies this close (metres): the
/// map keeps one merged point per 5 cm voxel, whose mean sits up to half a voxel's diagonal
/// (0.043 m) from the surface points it stands for. Read on benchmark 0-9 (`eval refer`,
/// referring mIoU): 0.035 / 0.05 / 0.075 / 0.1 m give 0.690 / 0.711 / 0.715 / 0.716; the rest
/// of the gain past 0.05 m is reach onto what touches the answer. Checked where it was not
/// read: 100-119 0.05 / 0.075 / 0.1 give 0.558 / 0.564 / 0.566, 8000-8019 (0.035 too) 0.605 /
/// 0.630 / 0.645 / 0.651: a longer reach gains 0.005-0.02 everywhere, not adopted yet.
pub const MEASURED_MATCH_M: f32 = 0.05;
/// Plus this many σ of the sensor's range noise at the pixel's depth: a reading within 3 σ of
/// the surface is on it (a choice, not fitted; only `realistic` noise exercises it).
pub const MEASURED_NOISE_SIGMAS: f32 = 3.0;
/// The search never reaches farther than this (metres; the grid's cell): twice the match
/// distance, so noise can widen it that far and no farther (a choice, not fitted).
pub const MEASURED_MAX_MATCH_M: f32 = 0.1;

/// Depth tolerance of the occlusion cut (metres).
pub const MASK_DEPTH_TOLERANCE: f32 = 0.1;
/// Masks draw each Gaussian at most this wide (σ, metres): two fifths of the map's 5 cm voxels,
/// so neighbouring points still close the gaps between them. Read on benchmark 0-9 (`eval
/// refer`, right answers' masks): uncapped, pixel precision / recall 0.76 / 0.92 and mIoU 0.64;
/// at 0.025 m 0.88 / 0.84 and 0.72; at 0.02 m 0.92 / 0.79 and 0.72; at 0.015 m 0.94 / 0.61 and 0.64.
pub const MASK_MAX_SIGMA_M: f32 = 0.02;

/// The map's points around an answer, each with whose it is, on a dense grid: built once per
/// answer, looked up once per measured pixel.
#[derive(Debug, Clone)]
pub struct AnswerVolume {
    lo: Vec3,
    dims: [usize; 3],
    /// Per cell (x fastest), where its points start in `points`; one more entry at the end.
    starts: Vec<u32>,
    /// (point, 0 for another instance's or 1 + the index of the chosen instance it belongs to).
    points: Vec<(Vec3, u16)>,
}

impl AnswerVolume {
    /// The points of `instances` (the whole map, in its order) within reach of the `chosen`
    /// ones (indices into `instances`); `None` when the chosen hold no finite point.
    pub fn new(instances: &[&Gaussians], chosen: &[usize]) -> Option<Self> {
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        for g in chosen.iter().filter_map(|&k| instances.get(k)) {
            for m in g.means.iter().filter(|m| m.is_finite()) {
                lo = lo.min(*m);
                hi = hi.max(*m);
            }
        }
        if !(lo.is_finite() && hi.is_finite()) {
            return None;
        }
        let cell = MEASURED_MAX_MATCH_M;
        let (lo, hi) = (lo - Vec3::splat(cell), hi + Vec3::splat(cell));
        let span = ((hi - lo) / cell).ceil().max(Vec3::ONE);
        let dims = [span.x as usize, span.y as usize, span.z as usize];
        let mut volume = Self {
            lo,
            dims,
            starts: Vec::new(),
            points: Vec::new(),
        };
        let mut tagged: Vec<(usize, Vec3, u16)> = Vec::new();
        for (k, g) in instances.iter().enumerate() {
            let tag = chosen
                .iter()
                .position(|&c| c == k)
                .map_or(0, |p| (p + 1).min(usize::from(u16::MAX)) as u16);
            for m in g.means.iter().filter(|m| m.is_finite()) {
                if let Some(cell) = volume.cell_of(*m) {
                    tagged.push((cell, *m, tag));
                }
            }
        }
        // A counting sort by cell: each cell's points lie together.
        let cells = dims[0] * dims[1] * dims[2];
        let mut counts = vec![0u32; cells + 1];
        for (cell, _, _) in &tagged {
            counts[cell + 1] += 1;
        }
        for c in 1..=cells {
            counts[c] += counts[c - 1];
        }
        let mut next = counts.clone();
        let mut points = vec![(Vec3::ZERO, 0u16); tagged.len()];
        for (cell, p, tag) in tagged {
            points[next[cell] as usize] = (p, tag);
            next[cell] += 1;
        }
        volume.starts = counts;
        volume.points = points;
        Some(volume)
    }

    /// The pixels of `keyframe` the volume can project to (columns, rows): the bounds of its
    /// corners' projections, a pixel wider; the whole image where a corner is behind the camera
    /// or the lens distorts (its outline then bends).
    fn pixel_bounds(&self, keyframe: &Keyframe) -> (Range<usize>, Range<usize>) {
        let camera = &keyframe.camera;
        let (w, h) = (camera.width as usize, camera.height as usize);
        let whole = (0..w, 0..h);
        if !camera.distortion.is_zero() {
            return whole;
        }
        let extent = Vec3::new(
            self.dims[0] as f32,
            self.dims[1] as f32,
            self.dims[2] as f32,
        );
        let hi = self.lo + MEASURED_MAX_MATCH_M * extent;
        let camera_from_world = keyframe.world_from_camera.inverse();
        let mut bounds = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
        for corner in 0..8 {
            let pick = |bit: usize, a: f32, b: f32| if corner & bit == 0 { a } else { b };
            let world = Vec3::new(
                pick(1, self.lo.x, hi.x),
                pick(2, self.lo.y, hi.y),
                pick(4, self.lo.z, hi.z),
            );
            let Some(px) = camera.project(camera_from_world.transform_point(world.as_dvec3()))
            else {
                return whole;
            };
            bounds = (bounds.0.min(px), bounds.1.max(px));
        }
        let clamp = |v: f64, n: usize| v.clamp(0.0, n as f64) as usize;
        (
            clamp(bounds.0.x.floor() - 1.0, w)..clamp(bounds.1.x.ceil() + 2.0, w),
            clamp(bounds.0.y.floor() - 1.0, h)..clamp(bounds.1.y.ceil() + 2.0, h),
        )
    }

    fn cell_coords(&self, p: Vec3) -> Option<[usize; 3]> {
        let c = (p - self.lo) / MEASURED_MAX_MATCH_M;
        let inside = |v: f32, n: usize| v >= 0.0 && v < n as f32;
        (inside(c.x, self.dims[0]) && inside(c.y, self.dims[1]) && inside(c.z, self.dims[2]))
            .then_some([c.x as usize, c.y as usize, c.z as usize])
    }

    fn cell_of(&self, p: Vec3) -> Option<usize> {
        self.cell_coords(p)
            .map(|[x, y, z]| x + self.dims[0] * (y + self.dims[1] * z))
    }

    /// Whose the nearest map point within `radius` of `p` is (0: another instance's), `None`
    /// when none lies that close. `radius` is capped at [`MEASURED_MAX_MATCH_M`].
    pub fn owner_near(&self, p: Vec3, radius: f32) -> Option<u16> {
        let [x, y, z] = self.cell_coords(p)?;
        let mut best = (radius.min(MEASURED_MAX_MATCH_M).powi(2), None);
        let range = |c: usize, n: usize| c.saturating_sub(1)..(c + 2).min(n);
        for cz in range(z, self.dims[2]) {
            for cy in range(y, self.dims[1]) {
                for cx in range(x, self.dims[0]) {
                    let cell = cx + self.dims[0] * (cy + self.dims[1] * cz);
                    let (start, end) = (self.starts[cell] as usize, self.starts[cell + 1] as usize);
                    for (q, tag) in &self.points[start..end] {
                        let d = q.distance_squared(p);
                        if d <= best.0 {
                            best = (d, Some(*tag));
                        }
                    }
                }
            }
        }
        best.1
    }
}

/// Per pixel of `keyframe`, given its measured z-depth (`depth`, row-major at the keyframe's
/// resolution; NaN or <= 0: no reading): 1 + the index of the chosen instance whose points the
/// reading lies on, 0 for none (and where nothing of the answer's surroundings projects); `None`
/// where the answer could be and there is no reading. `noise_at_1m` is the sensor's
/// range noise (σ at 1 m; σ grows with the square of the range).
pub fn measured_labels(
    volume: &AnswerVolume,
    keyframe: &Keyframe,
    depth: &[f32],
    noise_at_1m: Option<f32>,
) -> Vec<Option<u16>> {
    labels_of_readings(
        volume,
        keyframe,
        depth,
        &world_points(keyframe, depth),
        noise_at_1m,
    )
}

/// [`measured_labels`] in a view whose sensor depth the node kept: its readings' world points
/// are unprojected once per view ([`MeasuredDepth::world_points`]), not once per answer.
pub fn measured_view_labels(volume: &AnswerVolume, view: &MeasuredDepth) -> Vec<Option<u16>> {
    labels_of_readings(
        volume,
        &view.keyframe,
        &view.depth,
        view.world_points(),
        view.noise_at_1m,
    )
}

/// [`measured_labels`], given each reading's world point (`points`, NaN where none).
fn labels_of_readings(
    volume: &AnswerVolume,
    keyframe: &Keyframe,
    depth: &[f32],
    points: &[Vec3],
    noise_at_1m: Option<f32>,
) -> Vec<Option<u16>> {
    let (w, h) = (
        keyframe.camera.width as usize,
        keyframe.camera.height as usize,
    );
    let noise = noise_at_1m
        .filter(|n| n.is_finite() && *n > 0.0)
        .unwrap_or(0.0);
    let (columns, rows) = volume.pixel_bounds(keyframe);
    (0..w * h)
        .map(|p| {
            let (x, y) = (p % w, p / w);
            // Nothing of the answer projects there: no reading is needed to say so.
            if !(columns.contains(&x) && rows.contains(&y)) {
                return Some(0);
            }
            let d = *depth.get(p)?;
            let point = *points.get(p)?;
            if !(d.is_finite() && d > 0.0 && point.is_finite()) {
                return None;
            }
            let radius = MEASURED_MATCH_M + MEASURED_NOISE_SIGMAS * noise * d * d;
            Some(volume.owner_near(point, radius).unwrap_or(0))
        })
        .collect()
}

/// The answer's label image in `keyframe` (1 + the index into `answer`, 0 for none): where
/// `measured` (the view's depth at the keyframe's resolution and its noise) has a reading, the
/// instance whose points it lies on ([`measured_labels`]); elsewhere the splats of `answer`,
/// cut by `scene_depth` (the map's depth rendered at the keyframe's resolution; empty: no cut).
pub fn answer_labels(
    answer: &[&Gaussians],
    volume: Option<&AnswerVolume>,
    keyframe: &Keyframe,
    measured: Option<&MeasuredDepth>,
    scene_depth: &[f32],
) -> Vec<u16> {
    let (Some(view), Some(volume)) = (measured, volume) else {
        return label_image(answer, keyframe, scene_depth);
    };
    let measured = measured_view_labels(volume, view);
    // Splats are drawn only when the answer could be where the sensor read nothing.
    let splats = measured
        .iter()
        .any(Option::is_none)
        .then(|| label_image(answer, keyframe, scene_depth));
    measured
        .iter()
        .enumerate()
        .map(|(p, m)| m.unwrap_or_else(|| splats.as_ref().map_or(0, |s| s[p])))
        .collect()
}

/// The label image of `instances` in `keyframe`: pixel = 1 + the index of the instance seen
/// there, 0 for none. One render of them all with an owner channel (so the nearest wins), cut by
/// `scene_depth` (the whole map's rendered depth there, 0 = nothing) so what other instances hide
/// stays out.
pub fn label_image(instances: &[&Gaussians], keyframe: &Keyframe, scene_depth: &[f32]) -> Vec<u16> {
    let (w, h) = (
        keyframe.camera.width as usize,
        keyframe.camera.height as usize,
    );
    let mut all = Gaussians::with_dims(0, 0);
    // A pixel is the instance's whose Gaussians carry most of it (a single blended owner number
    // would mislabel the edge between two instances).
    let mut owner = Vec::new();
    for (k, g) in instances.iter().enumerate() {
        all.extend_geometry(g);
        owner.extend(std::iter::repeat_n(k as u32, g.len()));
    }
    if instances.is_empty() {
        return vec![0; w * h];
    }
    // A merged Gaussian stands for the points of one map voxel: drawn wider, it spills over the
    // object's outline (right answers' masks: pixel precision 0.76 at the splats' own scales).
    for scale in &mut all.scales {
        *scale = scale.min(glam::Vec3::splat(MASK_MAX_SIGMA_M));
    }
    let Ok(r) = render_labels(
        &all,
        &owner,
        &keyframe.camera,
        &keyframe.world_from_camera.inverse(),
        &RasterSettings::default(),
    ) else {
        return vec![0; w * h];
    };
    (0..w * h)
        .map(|p| {
            let d = r.depth[p];
            let reference = scene_depth.get(p).copied().unwrap_or(0.0);
            let unoccluded = reference <= 0.0 || d <= reference + MASK_DEPTH_TOLERANCE;
            match r.labels[p] {
                Some(k) if r.alpha[p] > MASK_ALPHA && unoccluded => {
                    (k as usize + 1).min(usize::from(u16::MAX)) as u16
                }
                _ => 0,
            }
        })
        .collect()
}

/// The map's points around the instances `ids` of `scene`'s map ([`measured_volume`]).
pub(super) fn answer_volume(scene: &ReferScene, ids: &[String]) -> Option<AnswerVolume> {
    let chosen: Vec<usize> = ids
        .iter()
        .filter_map(|id| scene.map.instances.iter().position(|i| &i.id == id))
        .collect();
    measured_volume(scene, &chosen)
}

/// The map's points around `scene`'s instances `chosen` (indices into its map), for masks cut by
/// measured depth; `None` when no keyframe of the snapshot kept its depth (nothing to cut by).
pub(crate) fn measured_volume(scene: &ReferScene, chosen: &[usize]) -> Option<AnswerVolume> {
    if !scene.measured.iter().any(Option::is_some) {
        return None;
    }
    let instances: Vec<&Gaussians> = scene.map.instances.iter().map(|i| &i.gaussians).collect();
    AnswerVolume::new(&instances, chosen)
}

/// The answer's labels in the snapshot's `k`-th keyframe: at the sensor's resolution, cut by its
/// depth, where the snapshot kept it; otherwise its splats at the keyframe's.
pub(crate) fn keyframe_labels<'s>(
    scene: &'s ReferScene,
    k: usize,
    keyframe: &'s Keyframe,
    answer: &[&Gaussians],
    volume: Option<&AnswerVolume>,
) -> (&'s Keyframe, Vec<u16>) {
    let scene_depth = scene.depths.get(k).map_or(&[][..], Vec::as_slice);
    match scene.measured.get(k).and_then(Option::as_ref) {
        Some(m) => {
            let kept = scene.measured_reference.get(k).map(Vec::as_slice);
            let reference = match kept {
                Some(r) if r.len() == m.depth.len() => std::borrow::Cow::Borrowed(r),
                _ => resampled(scene_depth, pixels(keyframe), pixels(&m.keyframe)).into(),
            };
            let labels = answer_labels(answer, volume, &m.keyframe, Some(m), &reference);
            (&m.keyframe, labels)
        }
        None => (keyframe, label_image(answer, keyframe, scene_depth)),
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::recon::camera::Camera;
    use crate::recon::Rigid;
    use glam::Quat;

    /// A square wall of Gaussians at depth `z` (camera frame = world frame) spanning x0..x1.
    pub(crate) fn wall(x0: f32, x1: f32, z: f32) -> Gaussians {
        let mut g = Gaussians::with_dims(0, 0);
        let mut x = x0;
        while x <= x1 {
            let mut y = -0.5;
            while y <= 0.5 {
                g.push(
                    Vec3::new(x, y, z),
                    0.99,
                    Vec3::splat(0.02),
                    Quat::IDENTITY,
                    Vec3::ONE,
                    &[],
                    &[],
                );
                y += 0.02;
            }
            x += 0.02;
        }
        g
    }

    /// 64 × 48, looking down +z from the origin (camera frame = world frame).
    fn keyframe() -> Keyframe {
        Keyframe {
            stamp_nanos: 0,
            camera: Camera::from_fov(64, 48, 1.2).unwrap(),
            world_from_camera: Rigid::default(),
        }
    }

    /// The depth a sensor at `keyframe()` measures of a plane at `far` with a panel at `near`
    /// in front of it over x in `panel` (metres).
    fn measured(near: f32, far: f32, panel: (f32, f32)) -> Vec<f32> {
        let camera = keyframe().camera;
        (0..64 * 48)
            .map(|p| {
                let ray = camera.ray(DVec2::new((p % 64) as f64, (p / 64) as f64));
                let x = (ray.x * f64::from(near)) as f32;
                if x >= panel.0 && x <= panel.1 {
                    near
                } else {
                    far
                }
            })
            .collect()
    }

    #[test]
    fn a_pixel_is_the_answer_s_where_its_depth_lies_on_the_answer_s_points() {
        // A panel 0.4 m wide at 2 m before a wall at 3 m; the sensor measured both.
        let (panel, back) = (wall(-0.2, 0.2, 2.0), wall(-1.5, 1.5, 3.0));
        let volume = AnswerVolume::new(&[&back, &panel], &[1]).unwrap();
        let depth = measured(2.0, 3.0, (-0.2, 0.2));
        let labels = measured_labels(&volume, &keyframe(), &depth, None);
        let row: Vec<u16> = labels[24 * 64..25 * 64]
            .iter()
            .map(|l| l.unwrap())
            .collect();
        let wide = row.iter().filter(|l| **l == 1).count() as f64;
        let panel_pixels = 0.4 / (2.0 / keyframe().camera.fx);
        assert!(
            (wide - panel_pixels).abs() <= 1.0,
            "{wide} of {panel_pixels:.1}"
        );
        // What the wall behind measured is the wall's, however near the panel's outline.
        assert!(row
            .iter()
            .enumerate()
            .all(|(x, l)| *l == 0 || (20..44).contains(&x)));
        assert_eq!(
            labels.iter().filter(|l| l.is_none()).count(),
            0,
            "every pixel has a reading"
        );
    }

    #[test]
    fn where_two_instances_touch_each_measured_point_goes_to_the_nearer() {
        let (left, right) = (wall(-0.6, 0.0, 2.0), wall(0.02, 0.6, 2.0));
        let volume = AnswerVolume::new(&[&left, &right], &[0, 1]).unwrap();
        let labels = measured_labels(&volume, &keyframe(), &measured(2.0, 2.0, (0.0, 0.0)), None);
        let row = &labels[24 * 64..25 * 64];
        assert_eq!(row[20], Some(1));
        assert_eq!(row[44], Some(2));
        // A reading 8 cm behind them (a surface the map does not hold): beyond a voxel's
        // reach, nobody's.
        let behind = measured_labels(
            &volume,
            &keyframe(),
            &measured(2.08, 2.08, (0.0, 0.0)),
            None,
        );
        assert_eq!(behind[24 * 64 + 20], Some(0));
        // Within it (3 cm, as a voxel's mean sits off the surface): still theirs.
        let near = measured_labels(
            &volume,
            &keyframe(),
            &measured(2.03, 2.03, (0.0, 0.0)),
            None,
        );
        assert_eq!(near[24 * 64 + 20], Some(1));
    }

    #[test]
    fn pixels_without_a_reading_are_left_to_the_splats() {
        let panel = wall(-0.2, 0.2, 2.0);
        let volume = AnswerVolume::new(&[&panel], &[0]).unwrap();
        // The sensor read nothing on the left half (a dark, shiny surface).
        let mut depth = measured(2.0, 3.0, (-0.2, 0.2));
        for (p, d) in depth.iter_mut().enumerate() {
            if p % 64 < 32 {
                *d = f32::NAN;
            }
        }
        let frame = keyframe();
        let splats = label_image(&[&panel], &frame, &[]);
        let view = MeasuredDepth::new(frame.clone(), depth, None);
        let labels = answer_labels(&[&panel], Some(&volume), &frame, Some(&view), &[]);
        let row = 24 * 64;
        assert_eq!(
            labels[row + 28],
            splats[row + 28],
            "no reading: the splats'"
        );
        assert_eq!(labels[row + 28], 1);
        assert_eq!(labels[row + 36], 1, "a reading on the panel");
        // Without a measured depth, the mask is the splats'.
        assert_eq!(
            answer_labels(&[&panel], Some(&volume), &frame, None, &[]),
            splats
        );
    }

    #[test]
    fn a_kept_view_labels_as_its_raw_depth_does_and_resamples_to_the_nearest_pixel() {
        // A panel before a wall, read with noise and with holes: the view's world points,
        // unprojected once and kept, give every answer the labels a fresh unprojection gives.
        let (panel, back) = (wall(-0.2, 0.2, 2.0), wall(-1.5, 1.5, 3.0));
        let mut depth = measured(2.0, 3.0, (-0.2, 0.2));
        for (p, d) in depth.iter_mut().enumerate() {
            if p % 7 == 0 {
                *d = f32::NAN;
            }
        }
        let view = MeasuredDepth::new(keyframe(), depth.clone(), Some(0.01));
        for chosen in [[1], [0]] {
            let volume = AnswerVolume::new(&[&back, &panel], &chosen).unwrap();
            let fresh = measured_labels(&volume, &keyframe(), &depth, Some(0.01));
            assert_eq!(measured_view_labels(&volume, &view), fresh);
            assert!(fresh.contains(&Some(1)) && fresh.contains(&None));
        }
        assert!(std::ptr::eq(view.world_points(), view.world_points()));
        // Nearest-pixel resampling, up and down, against the formula pixel by pixel.
        let image: Vec<f32> = (0..7 * 5).map(|v| v as f32).collect();
        for (from, to) in [((7, 5), (3, 4)), ((7, 5), (10, 11)), ((7, 5), (7, 5))] {
            let want: Vec<f32> = (0..to.0 * to.1)
                .map(|p| {
                    let x = ((p % to.0) * from.0 / to.0).min(from.0 - 1);
                    let y = ((p / to.0) * from.1 / to.1).min(from.1 - 1);
                    image[y * from.0 + x]
                })
                .collect();
            assert_eq!(resampled(&image, from, to), want, "{from:?} -> {to:?}");
        }
    }

    #[test]
    fn measured_masks_stay_finite_and_empty_on_degenerate_input() {
        let frame = keyframe();
        // No answer, or an answer without a finite point: no volume, masks from nothing.
        assert!(AnswerVolume::new(&[], &[]).is_none());
        let mut broken = wall(0.0, 0.1, 2.0);
        for m in &mut broken.means {
            *m = Vec3::NAN;
        }
        assert!(AnswerVolume::new(&[&broken], &[0]).is_none());
        assert!(answer_labels(&[], None, &frame, None, &[])
            .iter()
            .all(|l| *l == 0));
        // One point; NaN, negative, infinite depths; a short depth image; a NaN noise.
        let mut one = Gaussians::with_dims(0, 0);
        one.push(
            Vec3::new(0.0, 0.0, 2.0),
            1.0,
            Vec3::splat(0.01),
            glam::Quat::IDENTITY,
            Vec3::ONE,
            &[],
            &[],
        );
        let volume = AnswerVolume::new(&[&one, &broken], &[0]).unwrap();
        let centre = 24 * 64 + 32;
        for bad in [f32::NAN, -1.0, f32::INFINITY, 0.0] {
            let labels = measured_labels(&volume, &frame, &vec![bad; 64 * 48], Some(f32::NAN));
            assert_eq!(labels.len(), 64 * 48);
            assert_eq!(labels[centre], None, "no reading where the answer could be");
            assert_eq!(
                labels[0],
                Some(0),
                "nothing of the answer projects to the corner"
            );
        }
        let short = measured_labels(&volume, &frame, &[2.0; 5], None);
        assert_eq!(short[centre], None, "beyond the image's readings");
        let right = measured_labels(&volume, &frame, &vec![2.0; 64 * 48], Some(f32::NAN));
        assert_eq!(right[centre], Some(1));
        assert_eq!(
            volume.owner_near(Vec3::new(0.0, 0.0, 2.03), f32::INFINITY),
            Some(1)
        );
        assert_eq!(volume.owner_near(Vec3::NAN, 0.05), None);
        assert!(resampled(&[1.0; 3], (2, 2), (4, 4)).is_empty());
        assert_eq!(
            resampled(&[1.0, 2.0], (2, 1), (4, 1)),
            vec![1.0, 1.0, 2.0, 2.0]
        );
    }
    #[test]
    fn a_mask_keeps_to_its_instances_outline_however_wide_its_gaussians_were_merged() {
        // A 0.6 m wall at 2 m of Gaussians 5 cm apart (one per map voxel), each drawn as wide as
        // voxel merging made it (σ 8 cm): its mask is as wide as the wall, not a splat more.
        let mut wall = Gaussians::with_dims(0, 0);
        for i in 0..=12 {
            for j in 0..=20 {
                let at = Vec3::new(-0.3 + 0.05 * i as f32, -0.5 + 0.05 * j as f32, 2.0);
                wall.push(
                    at,
                    0.99,
                    Vec3::splat(0.08),
                    Quat::IDENTITY,
                    Vec3::ONE,
                    &[],
                    &[],
                );
            }
        }
        let frame = keyframe();
        let labels = label_image(&[&wall], &frame, &[]);
        let row = &labels[24 * 64..25 * 64];
        let wide = row.iter().filter(|l| **l == 1).count() as f64;
        let metres_per_pixel = 2.0 / frame.camera.fx;
        let wall_pixels = 0.6 / metres_per_pixel;
        assert!(
            wide >= wall_pixels - 1.0,
            "{wide} of {wall_pixels:.1} pixels: holes"
        );
        assert!(
            wide <= wall_pixels + 2.0,
            "{wide} of {wall_pixels:.1} pixels: spilled"
        );
    }

    #[test]
    fn adjacent_instances_get_their_own_labels_and_no_third_at_the_seam() {
        let (left, right) = (wall(-0.6, 0.0, 2.0), wall(0.02, 0.6, 2.0));
        let labels = label_image(&[&left, &right], &keyframe(), &[]);
        let count = |v: u16| labels.iter().filter(|l| **l == v).count();
        assert!(
            count(1) > 100 && count(2) > 100,
            "{} {}",
            count(1),
            count(2)
        );
        assert!(labels.iter().all(|l| *l <= 2));
        // Row through the middle: left of centre is 1, right of centre is 2.
        let row = &labels[24 * 64..25 * 64];
        assert_eq!(row[20], 1);
        assert_eq!(row[44], 2);
    }

    #[test]
    fn what_the_map_hides_is_cut_from_the_mask_and_nothing_renders_nothing() {
        let behind = wall(-0.3, 0.3, 3.0);
        // The map's depth says a nearer surface (at 1 m) covers the left half of the image.
        let depth: Vec<f32> = (0..64 * 48)
            .map(|p| if p % 64 < 32 { 1.0 } else { 0.0 })
            .collect();
        let labels = label_image(&[&behind], &keyframe(), &depth);
        let row = &labels[24 * 64..25 * 64];
        assert_eq!(row[28], 0, "occluded");
        assert_eq!(row[36], 1, "visible");
        assert!(label_image(&[], &keyframe(), &[]).iter().all(|l| *l == 0));
    }
}
