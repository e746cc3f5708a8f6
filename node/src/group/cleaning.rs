//! Map hygiene at the window level (DESIGN §5.6), as mapping systems do it: flying pixels (depths
//! between two surfaces along a silhouette, which lift to points in the air) and nearly
//! transparent Gaussians are not grouped into objects, and a
//! cluster whose points fall apart in space is split into its 3D connected components, the small
//! ones dropped as noise. Embeddings alike across the room (two identical chairs, a chair and a
//! patch of floor the model was unsure of) then no longer make one instance with a room-sized box.

use std::collections::VecDeque;

use rustc_hash::FxHashMap;

use glam::Vec3;

/// Defaults, chosen on the benchmark split's map evaluation (`groupforward eval map`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CleaningParams {
    /// A pixel is flying when no 4-neighbour's depth is within this share of its own.
    pub flying_ratio: f32,
    /// Gaussians less opaque than this are not grouped.
    pub min_opacity: f32,
    /// Voxel size of the connectivity grid (metres): points in touching voxels (26-neighbourhood)
    /// are connected. Components smaller than HDBSCAN's `min_cluster_size` are noise.
    pub cell: f32,
}

impl Default for CleaningParams {
    fn default() -> Self {
        Self {
            flying_ratio: 0.1,
            min_opacity: 0.05,
            cell: 0.12,
        }
    }
}

/// Per pixel of `views` depth maps of `width` × `height` (view-major): whether it is a flying
/// pixel, one whose depth agrees (within `ratio` of its own) with none of its 4-neighbours, as the
/// mixed depths a sensor or a network returns along an object's silhouette do, or has no valid
/// depth. Both sides of a true depth edge agree with their own surface and stay.
pub fn flying_pixels(depth: &[f32], width: usize, height: usize, ratio: f32) -> Vec<bool> {
    let plane = width * height;
    let mut flying = vec![true; depth.len()];
    if plane == 0 {
        return flying;
    }
    for (i, out) in flying.iter_mut().enumerate() {
        let d = depth[i];
        if !(d.is_finite() && d > 0.0) {
            continue;
        }
        let (base, p) = (i - i % plane, i % plane);
        let (x, y) = (p % width, p / width);
        let mut neighbours = [None; 4];
        if x > 0 {
            neighbours[0] = Some(base + p - 1);
        }
        if x + 1 < width {
            neighbours[1] = Some(base + p + 1);
        }
        if y > 0 {
            neighbours[2] = Some(base + p - width);
        }
        if y + 1 < height {
            neighbours[3] = Some(base + p + width);
        }
        *out = !neighbours.into_iter().flatten().any(|n| {
            let e = depth[n];
            e.is_finite() && e > 0.0 && (e - d).abs() <= ratio * d
        });
    }
    flying
}

/// Split every cluster of `labels` (one per point; -1 noise) into the connected components of
/// its points on a voxel grid of `cell`; components of fewer than `min_points` points become
/// noise. Labels are renumbered 0..K, each cluster's components in order of size; returns K.
pub fn split_components(
    labels: &mut [i32],
    points: &[Vec3],
    cell: f32,
    min_points: usize,
) -> usize {
    let clusters = labels
        .iter()
        .copied()
        .max()
        .map_or(0, |m| (m + 1).max(0) as usize);
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); clusters];
    for i in 0..labels.len() {
        if let Ok(k) = usize::try_from(labels[i]) {
            if points[i].is_finite() {
                members[k].push(i);
            } else {
                labels[i] = -1;
            }
        }
    }
    let cell = if cell.is_finite() && cell > 0.0 {
        cell
    } else {
        1.0
    };
    let mut next = 0i32;
    for points_of_cluster in members {
        let key = |p: Vec3| {
            let v = (p / cell).floor();
            (v.x as i32, v.y as i32, v.z as i32)
        };
        let mut voxels: FxHashMap<(i32, i32, i32), Vec<usize>> = FxHashMap::default();
        for &i in &points_of_cluster {
            voxels.entry(key(points[i])).or_default().push(i);
        }
        // Breadth-first over occupied voxels; each component's points.
        let mut component_of: FxHashMap<(i32, i32, i32), usize> = FxHashMap::default();
        let mut components: Vec<Vec<usize>> = Vec::new();
        let mut keys: Vec<(i32, i32, i32)> = voxels.keys().copied().collect();
        keys.sort_unstable();
        for start in keys {
            if component_of.contains_key(&start) {
                continue;
            }
            let id = components.len();
            let mut found = Vec::new();
            let mut queue = VecDeque::from([start]);
            component_of.insert(start, id);
            while let Some(v) = queue.pop_front() {
                found.extend_from_slice(&voxels[&v]);
                for dx in -1..=1 {
                    for dy in -1..=1 {
                        for dz in -1..=1 {
                            let n = (v.0 + dx, v.1 + dy, v.2 + dz);
                            if voxels.contains_key(&n) && !component_of.contains_key(&n) {
                                component_of.insert(n, id);
                                queue.push_back(n);
                            }
                        }
                    }
                }
            }
            components.push(found);
        }
        components.sort_by_key(|c| std::cmp::Reverse(c.len()));
        for component in components {
            let label = if component.len() >= min_points {
                next += 1;
                next - 1
            } else {
                -1
            };
            for i in component {
                labels[i] = label;
            }
        }
    }
    next as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blob(centre: Vec3, n: usize) -> Vec<Vec3> {
        (0..n)
            .map(|i| centre + Vec3::new((i % 5) as f32, (i / 5 % 5) as f32, (i / 25) as f32) * 0.02)
            .collect()
    }

    #[test]
    fn two_blobs_in_one_cluster_become_two_instances_and_specks_noise() {
        let mut points = blob(Vec3::ZERO, 100);
        points.extend(blob(Vec3::new(3.0, 0.0, 0.0), 60));
        points.extend(blob(Vec3::new(0.0, 2.0, 0.0), 5));
        let mut labels = vec![0; points.len()];
        let clusters = split_components(&mut labels, &points, 0.08, 30);
        assert_eq!(clusters, 2);
        assert!(
            labels[..100].iter().all(|&l| l == 0),
            "the largest part keeps label 0"
        );
        assert!(labels[100..160].iter().all(|&l| l == 1));
        assert!(
            labels[160..].iter().all(|&l| l == -1),
            "a five-point speck is noise"
        );
    }

    #[test]
    fn a_connected_wall_stays_one_instance_and_noise_stays_noise() {
        // A 3 x 2 m wall sampled every 5 cm, plus noise points.
        let mut points: Vec<Vec3> = (0..60 * 40)
            .map(|i| Vec3::new((i % 60) as f32 * 0.05, 0.0, (i / 60) as f32 * 0.05))
            .collect();
        points.push(Vec3::new(9.0, 9.0, 9.0));
        let mut labels = vec![0; points.len()];
        *labels.last_mut().unwrap() = -1;
        assert_eq!(split_components(&mut labels, &points, 0.08, 30), 1);
        assert!(labels[..2400].iter().all(|&l| l == 0));
        assert_eq!(labels[2400], -1);
    }

    #[test]
    fn empty_single_and_non_finite_inputs_are_handled() {
        assert_eq!(split_components(&mut [], &[], 0.08, 30), 0);
        let mut one = [0];
        assert_eq!(split_components(&mut one, &[Vec3::ZERO], 0.08, 1), 1);
        assert_eq!(one, [0]);
        let mut labels = [0, 0, 0];
        let points = [Vec3::NAN, Vec3::ZERO, Vec3::new(0.01, 0.0, 0.0)];
        assert_eq!(split_components(&mut labels, &points, 0.08, 2), 1);
        assert_eq!(labels, [-1, 0, 0]);
        // A zero or NaN cell falls back to a metre instead of dividing by zero.
        let mut labels = [0, 0];
        assert_eq!(
            split_components(&mut labels, &[Vec3::ZERO, Vec3::X * 0.5], f32::NAN, 1),
            1
        );
    }

    #[test]
    fn flying_pixels_go_and_both_sides_of_an_edge_stay() {
        // One 5 x 3 view: a near box (1 m) on a far wall (3 m); between them one pixel at 2 m
        // that agrees with neither (a flying pixel), and one invalid pixel.
        #[rustfmt::skip]
        let depth = [
            3.0, 3.0, 3.0, 3.0, 3.0,
            3.0, 1.0, 1.0, 2.0, 3.0,
            f32::NAN, 1.0, 1.0, 3.0, 3.0,
        ];
        let flying = flying_pixels(&depth, 5, 3, 0.1);
        let expected: Vec<bool> = (0..15).map(|i| i == 8 || i == 10).collect();
        assert_eq!(flying, expected);
        // A lone valid pixel among invalid ones has nothing to agree with.
        let lone = [f32::NAN, 2.0, f32::NAN];
        assert_eq!(flying_pixels(&lone, 3, 1, 0.1), [true, true, true]);
        assert!(flying_pixels(&[], 0, 0, 0.1).is_empty());
    }
}
