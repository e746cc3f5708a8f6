//! 3D Gaussians in struct-of-arrays form: centre, opacity, scale, rotation, colour, an instance
//! embedding and optional extra channels per Gaussian. Pixel-aligned predictions (one Gaussian per
//! pixel of each view) lift to world space; voxel downsampling bounds their number.

use rustc_hash::FxHashMap;

use glam::{DVec2, Quat, Vec3};

use super::camera::Camera;
use super::Rigid;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GaussianError {
    #[error("Gaussian {index}: non-finite {field}")]
    NonFinite { index: usize, field: &'static str },
    #[error("{field} has {got} values, expected {expected}")]
    Length {
        field: &'static str,
        got: usize,
        expected: usize,
    },
    #[error("voxel size must be positive and finite, got {0}")]
    BadVoxel(f32),
}

pub type Result<T> = std::result::Result<T, GaussianError>;

/// A set of Gaussians; every per-Gaussian vector has `len()` entries (embeddings and extras
/// `len() * dim`).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Gaussians {
    pub means: Vec<Vec3>,
    pub opacities: Vec<f32>,
    /// Standard deviations along the local axes (metres). Signs are ignored.
    pub scales: Vec<Vec3>,
    /// Local-to-world rotations; zero or non-unit quaternions are normalised (zero → identity).
    pub rotations: Vec<Quat>,
    pub colors: Vec<Vec3>,
    pub embedding_dim: usize,
    pub embeddings: Vec<f32>,
    pub extra_dim: usize,
    pub extra: Vec<f32>,
}

impl Gaussians {
    /// Append `other`'s geometry and colour only (no embeddings or extra channels): what a
    /// render of several instances together needs.
    /// `self` must carry no embeddings or extras itself (`with_dims(0, 0)`).
    pub fn extend_geometry(&mut self, other: &Gaussians) {
        debug_assert!(self.embedding_dim == 0 && self.extra_dim == 0);
        self.means.extend_from_slice(&other.means);
        self.opacities.extend_from_slice(&other.opacities);
        self.scales.extend_from_slice(&other.scales);
        self.rotations.extend_from_slice(&other.rotations);
        self.colors.extend_from_slice(&other.colors);
    }

    pub fn with_dims(embedding_dim: usize, extra_dim: usize) -> Self {
        Self {
            embedding_dim,
            extra_dim,
            ..Self::default()
        }
    }

    pub fn len(&self) -> usize {
        self.means.len()
    }

    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    pub fn embedding(&self, i: usize) -> &[f32] {
        &self.embeddings[i * self.embedding_dim..(i + 1) * self.embedding_dim]
    }

    /// Append one Gaussian.
    #[allow(clippy::too_many_arguments)] // one value per attribute, named at every call site
    pub fn push(
        &mut self,
        mean: Vec3,
        opacity: f32,
        scale: Vec3,
        rotation: Quat,
        color: Vec3,
        embedding: &[f32],
        extra: &[f32],
    ) {
        self.means.push(mean);
        self.opacities.push(opacity);
        self.scales.push(scale);
        self.rotations.push(rotation);
        self.colors.push(color);
        self.embeddings.extend_from_slice(embedding);
        self.extra.extend_from_slice(extra);
    }

    /// Check lengths and reject NaN / Inf anywhere: the boundary check of everything downstream.
    pub fn validate(&self) -> Result<()> {
        let n = self.len();
        let check_len = |field, got, expected| {
            if got == expected {
                Ok(())
            } else {
                Err(GaussianError::Length {
                    field,
                    got,
                    expected,
                })
            }
        };
        check_len("opacities", self.opacities.len(), n)?;
        check_len("scales", self.scales.len(), n)?;
        check_len("rotations", self.rotations.len(), n)?;
        check_len("colors", self.colors.len(), n)?;
        check_len("embeddings", self.embeddings.len(), n * self.embedding_dim)?;
        check_len("extra", self.extra.len(), n * self.extra_dim)?;
        for i in 0..n {
            let non_finite = |field| Err(GaussianError::NonFinite { index: i, field });
            if !self.means[i].is_finite() {
                return non_finite("mean");
            }
            if !self.opacities[i].is_finite() {
                return non_finite("opacity");
            }
            if !self.scales[i].is_finite() {
                return non_finite("scale");
            }
            if !self.rotations[i].is_finite() {
                return non_finite("rotation");
            }
            if !self.colors[i].is_finite() {
                return non_finite("color");
            }
            if !self.embedding(i).iter().all(|v| v.is_finite()) {
                return non_finite("embedding");
            }
            let extra = &self.extra[i * self.extra_dim..(i + 1) * self.extra_dim];
            if !extra.iter().all(|v| v.is_finite()) {
                return non_finite("extra");
            }
        }
        Ok(())
    }

    /// Append all of `other` (same dims).
    pub fn extend(&mut self, other: &Gaussians) {
        self.means.extend_from_slice(&other.means);
        self.opacities.extend_from_slice(&other.opacities);
        self.scales.extend_from_slice(&other.scales);
        self.rotations.extend_from_slice(&other.rotations);
        self.colors.extend_from_slice(&other.colors);
        self.embeddings.extend_from_slice(&other.embeddings);
        self.extra.extend_from_slice(&other.extra);
    }

    /// The Gaussians at `indices`, in that order (each index must be in range).
    pub fn select(&self, indices: impl IntoIterator<Item = usize>) -> Gaussians {
        let mut out = Gaussians::with_dims(self.embedding_dim, self.extra_dim);
        for i in indices {
            out.push(
                self.means[i],
                self.opacities[i],
                self.scales[i],
                self.rotations[i],
                self.colors[i],
                self.embedding(i),
                &self.extra[i * self.extra_dim..(i + 1) * self.extra_dim],
            );
        }
        out
    }
}

/// A normalised rotation; a zero (or non-finite-norm) quaternion is the identity.
pub fn safe_rotation(q: Quat) -> Quat {
    let norm = q.length();
    if norm > 1e-12 && norm.is_finite() {
        q / norm
    } else {
        Quat::IDENTITY
    }
}

/// One view of a pixel-aligned prediction, row-major `height × width`. Attribute slices hold one
/// entry per pixel (embeddings `embedding_dim` per pixel).
#[derive(Debug, Clone, Copy)]
pub struct PixelAligned<'a> {
    pub width: usize,
    pub height: usize,
    /// Metric depth along the optical axis; non-finite or non-positive pixels make no Gaussian.
    pub depth: &'a [f32],
    pub opacity: &'a [f32],
    /// Scale in pixels of the footprint at unit depth; multiplied by depth / focal length on lifting
    /// so a Gaussian covers about its pixel at any distance.
    pub scale: &'a [[f32; 3]],
    /// Camera-frame rotation (xyzw).
    pub rotation: &'a [[f32; 4]],
    pub color: &'a [[f32; 3]],
    pub embedding_dim: usize,
    pub embedding: &'a [f32],
}

/// Lift one view to world-space Gaussians.
pub fn lift(
    view: &PixelAligned<'_>,
    camera: &Camera,
    world_from_camera: &Rigid,
) -> Result<Gaussians> {
    let n = view.width * view.height;
    for (field, got, expected) in [
        ("depth", view.depth.len(), n),
        ("opacity", view.opacity.len(), n),
        ("scale", view.scale.len(), n),
        ("rotation", view.rotation.len(), n),
        ("color", view.color.len(), n),
        ("embedding", view.embedding.len(), n * view.embedding_dim),
    ] {
        if got != expected {
            return Err(GaussianError::Length {
                field,
                got,
                expected,
            });
        }
    }
    let mut out = Gaussians::with_dims(view.embedding_dim, 0);
    let rotation = world_from_camera.rotation.as_quat();
    let focal = ((camera.fx + camera.fy) / 2.0) as f32;
    for v in 0..view.height {
        for u in 0..view.width {
            let i = v * view.width + u;
            let depth = view.depth[i];
            if !(depth.is_finite() && depth > 0.0) {
                continue;
            }
            let p_camera = camera.unproject(DVec2::new(u as f64, v as f64), f64::from(depth));
            let mean = world_from_camera.transform_point(p_camera).as_vec3();
            let [qx, qy, qz, qw] = view.rotation[i];
            let local = safe_rotation(Quat::from_xyzw(qx, qy, qz, qw));
            let scale = Vec3::from_array(view.scale[i]).abs() * depth / focal;
            out.push(
                mean,
                view.opacity[i],
                scale,
                rotation * local,
                Vec3::from_array(view.color[i]),
                &view.embedding[i * view.embedding_dim..(i + 1) * view.embedding_dim],
                &[],
            );
        }
    }
    out.validate()?;
    Ok(out)
}

/// Merge Gaussians that fall into the same voxel of side `voxel`: opacity-weighted mean centre,
/// colour, embedding and extras; the largest opacity; the mean scale grown by the spread of the
/// merged centres; the rotation of the most opaque member. Output order is deterministic (first
/// occurrence of each voxel).
pub fn voxel_downsample(g: &Gaussians, voxel: f32) -> Result<Gaussians> {
    if !(voxel.is_finite() && voxel > 0.0) {
        return Err(GaussianError::BadVoxel(voxel));
    }
    g.validate()?;
    // Points grouped by voxel (a counting sort: voxels in the order their first point comes,
    // points in index order within each) with no allocation per voxel: a vector per voxel
    // and per average was most of a window's fusion.
    let mut slots: FxHashMap<(i64, i64, i64), usize> = FxHashMap::default();
    let mut slot_of = Vec::with_capacity(g.len());
    let mut sizes: Vec<usize> = Vec::new();
    for mean in &g.means {
        let key = (
            (mean.x / voxel).floor() as i64,
            (mean.y / voxel).floor() as i64,
            (mean.z / voxel).floor() as i64,
        );
        let next = sizes.len();
        let slot = *slots.entry(key).or_insert(next);
        if slot == next {
            sizes.push(0);
        }
        sizes[slot] += 1;
        slot_of.push(slot);
    }
    let mut starts = Vec::with_capacity(sizes.len() + 1);
    starts.push(0);
    for size in &sizes {
        starts.push(starts[starts.len() - 1] + size);
    }
    let mut order = vec![0usize; g.len()];
    let mut fill = starts.clone();
    for (i, &slot) in slot_of.iter().enumerate() {
        order[fill[slot]] = i;
        fill[slot] += 1;
    }
    let mut out = Gaussians::with_dims(g.embedding_dim, g.extra_dim);
    let (mut embedding, mut extra) = (vec![0.0; g.embedding_dim], vec![0.0; g.extra_dim]);
    // Weights: opacity, with a floor so fully transparent groups still average.
    let weight = |i: usize| g.opacities[i].max(0.0) + 1e-6;
    for bounds in starts.windows(2) {
        let group = &order[bounds[0]..bounds[1]];
        let total: f32 = group.iter().map(|&i| weight(i)).sum();
        let mean = group.iter().map(|&i| g.means[i] * weight(i)).sum::<Vec3>() / total;
        let color = group.iter().map(|&i| g.colors[i] * weight(i)).sum::<Vec3>() / total;
        embedding.fill(0.0);
        extra.fill(0.0);
        for &i in group {
            let w = weight(i);
            for (e, v) in embedding.iter_mut().zip(g.embedding(i)) {
                *e += v * w / total;
            }
            for (e, v) in extra
                .iter_mut()
                .zip(&g.extra[i * g.extra_dim..(i + 1) * g.extra_dim])
            {
                *e += v * w / total;
            }
        }
        let spread = (group
            .iter()
            .map(|&i| (g.means[i] - mean).length_squared())
            .sum::<f32>()
            / group.len() as f32)
            .sqrt();
        let scale = group.iter().map(|&i| g.scales[i].abs()).sum::<Vec3>() / group.len() as f32
            + Vec3::splat(spread);
        let most_opaque = group
            .iter()
            .copied()
            .max_by(|&a, &b| g.opacities[a].total_cmp(&g.opacities[b]).then(b.cmp(&a)))
            .unwrap_or(group[0]);
        let opacity = g.opacities[most_opaque];
        out.push(
            mean,
            opacity,
            scale,
            safe_rotation(g.rotations[most_opaque]),
            color,
            &embedding,
            &extra,
        );
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;

    type ViewData = (
        Vec<f32>,
        Vec<f32>,
        Vec<[f32; 3]>,
        Vec<[f32; 4]>,
        Vec<[f32; 3]>,
        Vec<f32>,
    );

    fn view_data(w: usize, h: usize, depth: f32) -> ViewData {
        let n = w * h;
        (
            vec![depth; n],
            vec![0.8; n],
            vec![[1.0, 1.0, 0.1]; n],
            vec![[0.0, 0.0, 0.0, 1.0]; n],
            vec![[0.2, 0.4, 0.6]; n],
            (0..n * 2).map(|i| i as f32).collect(),
        )
    }

    #[test]
    fn lifting_places_pixels_at_their_depth_in_the_world() {
        let camera = Camera::pinhole(4, 3, 100.0, 100.0, 2.0, 1.0).unwrap();
        let (depth, opacity, scale, rotation, color, embedding) = view_data(4, 3, 2.0);
        let view = PixelAligned {
            width: 4,
            height: 3,
            depth: &depth,
            opacity: &opacity,
            scale: &scale,
            rotation: &rotation,
            color: &color,
            embedding_dim: 2,
            embedding: &embedding,
        };
        let world_from_camera = Rigid::new(DQuat::IDENTITY, glam::DVec3::new(0.0, 0.0, 1.0));
        let g = lift(&view, &camera, &world_from_camera).unwrap();
        assert_eq!(g.len(), 12);
        // Pixel (2, 1) is the principal point: straight ahead.
        let centre = g.means[4 + 2];
        assert!((centre - Vec3::new(0.0, 0.0, 3.0)).length() < 1e-6);
        assert_eq!(g.embedding(5), &[10.0, 11.0]);
        // Footprint scales with depth / focal.
        assert!((g.scales[0].x - 2.0 / 100.0).abs() < 1e-7);
    }

    #[test]
    fn invalid_depth_makes_no_gaussian_and_nan_attributes_are_rejected() {
        let camera = Camera::pinhole(2, 1, 10.0, 10.0, 1.0, 0.5).unwrap();
        let (mut depth, opacity, scale, rotation, mut color, embedding) = view_data(2, 1, 1.0);
        depth[0] = f32::NAN;
        let make = |depth: &[f32], color: &[[f32; 3]]| {
            lift(
                &PixelAligned {
                    width: 2,
                    height: 1,
                    depth,
                    opacity: &opacity,
                    scale: &scale,
                    rotation: &rotation,
                    color,
                    embedding_dim: 2,
                    embedding: &embedding,
                },
                &camera,
                &Rigid::IDENTITY,
            )
        };
        assert_eq!(make(&depth, &color).unwrap().len(), 1);
        depth[0] = -1.0;
        assert_eq!(make(&depth, &color).unwrap().len(), 1);
        color[1][0] = f32::INFINITY;
        assert!(matches!(
            make(&depth, &color),
            Err(GaussianError::NonFinite { field: "color", .. })
        ));
        assert!(matches!(
            make(&depth[..1], &color),
            Err(GaussianError::Length { field: "depth", .. })
        ));
    }

    #[test]
    fn voxel_downsampling_merges_by_voxel_and_keeps_attributes_meaningful() {
        let mut g = Gaussians::with_dims(1, 1);
        g.push(
            Vec3::new(0.01, 0.01, 0.01),
            1.0,
            Vec3::splat(0.01),
            Quat::IDENTITY,
            Vec3::X,
            &[1.0],
            &[2.0],
        );
        g.push(
            Vec3::new(0.03, 0.01, 0.01),
            1.0,
            Vec3::splat(0.01),
            Quat::IDENTITY,
            Vec3::Y,
            &[3.0],
            &[4.0],
        );
        g.push(
            Vec3::new(0.5, 0.5, 0.5),
            0.5,
            Vec3::splat(0.02),
            Quat::from_xyzw(0.0, 0.0, 0.0, 0.0),
            Vec3::Z,
            &[5.0],
            &[6.0],
        );
        let d = voxel_downsample(&g, 0.1).unwrap();
        assert_eq!(d.len(), 2);
        assert!((d.means[0] - Vec3::new(0.02, 0.01, 0.01)).length() < 1e-6);
        assert!((d.colors[0] - Vec3::new(0.5, 0.5, 0.0)).length() < 1e-6);
        assert!((d.embeddings[0] - 2.0).abs() < 1e-5 && (d.extra[0] - 3.0).abs() < 1e-5);
        assert!(d.scales[0].x > 0.01);
        assert_eq!(d.rotations[1], Quat::IDENTITY);
        d.validate().unwrap();
        assert!(voxel_downsample(&g, 0.0).is_err());
        assert!(voxel_downsample(&Gaussians::default(), 0.1)
            .unwrap()
            .is_empty());
    }

    #[test]
    fn voxels_come_in_the_order_of_their_first_point_whatever_the_interleaving() {
        // Points of three voxels interleaved (b, a, b, c, a, b): each voxel averages its own
        // points, the voxels come out in the order their first point came, and the rotation is
        // the most opaque point's, the first of equals.
        let mut g = Gaussians::with_dims(1, 0);
        let points = [
            (Vec3::new(1.01, 0.0, 0.0), 0.5, 1.0),
            (Vec3::new(0.01, 0.0, 0.0), 0.9, 2.0),
            (Vec3::new(1.03, 0.0, 0.0), 0.5, 3.0),
            (Vec3::new(2.05, 0.0, 0.0), 0.2, 4.0),
            (Vec3::new(0.03, 0.0, 0.0), 0.9, 6.0),
            (Vec3::new(1.05, 0.0, 0.0), 0.5, 5.0),
        ];
        for (k, &(mean, opacity, embedding)) in points.iter().enumerate() {
            let rotation = Quat::from_rotation_z(k as f32 * 0.1);
            g.push(
                mean,
                opacity,
                Vec3::splat(0.01),
                rotation,
                Vec3::ONE,
                &[embedding],
                &[],
            );
        }
        let d = voxel_downsample(&g, 0.1).unwrap();
        assert_eq!(d.len(), 3);
        assert!((d.means[0] - Vec3::new(1.03, 0.0, 0.0)).length() < 1e-5);
        assert!((d.means[1] - Vec3::new(0.02, 0.0, 0.0)).length() < 1e-5);
        assert!((d.means[2] - Vec3::new(2.05, 0.0, 0.0)).length() < 1e-5);
        assert!((d.embeddings[0] - 3.0).abs() < 1e-5);
        assert!((d.embeddings[1] - 4.0).abs() < 1e-5);
        assert_eq!(d.opacities, [0.5, 0.9, 0.2]);
        assert!(d.rotations[0].angle_between(Quat::from_rotation_z(0.0)) < 1e-5);
        assert!(d.rotations[1].angle_between(Quat::from_rotation_z(0.1)) < 1e-5);
    }

    #[test]
    fn zero_and_non_unit_quaternions_are_normalised() {
        assert_eq!(
            safe_rotation(Quat::from_xyzw(0.0, 0.0, 0.0, 0.0)),
            Quat::IDENTITY
        );
        assert!((safe_rotation(Quat::from_xyzw(0.0, 0.0, 0.0, 5.0)).length() - 1.0).abs() < 1e-6);
        assert_eq!(
            safe_rotation(Quat::from_xyzw(f32::NAN, 0.0, 0.0, 1.0)),
            Quat::IDENTITY
        );
    }
}
