//! An answer as the `Refer` service returns it: per chosen instance its pose and gravity-aligned
//! box, its Gaussians as a PointCloud2 with an `instance_id` field, and its masks rendered into
//! the snapshot's keyframes (and into the request's view, if one was given), cut by the map's
//! rendered depth so occluded parts stay out.

use groupforward_msgs::builtin_interfaces::Time;
use groupforward_msgs::geometry_msgs::{Point, Pose, Quaternion, Vector3};
use groupforward_msgs::gf_msgs::{Candidate, InstanceMasks, ReferResponse};
use groupforward_msgs::sensor_msgs::{Image, PointCloud2, PointField};
use groupforward_msgs::std_msgs::Header;
use groupforward_msgs::vision_msgs::BoundingBox3D;

use super::masks::{answer_labels, resampled, AnswerVolume};
use super::scene::ReferScene;
use super::Answer;
use crate::frame::Keyframe;
use crate::recon::boxes::OrientedBox;
use crate::recon::gaussians::Gaussians;
use crate::recon::raster::{render_labels, RasterSettings};

/// Depth tolerance of the occlusion cut (metres).
pub const MASK_DEPTH_TOLERANCE: f32 = 0.1;
/// Masks draw each Gaussian at most this wide (σ, metres): two fifths of the map's 5 cm voxels,
/// so neighbouring points still close the gaps between them. Read on benchmark 0-9 (`eval
/// refer`, right answers' masks): uncapped, pixel precision / recall 0.76 / 0.92 and mIoU 0.64;
/// at 0.025 m 0.88 / 0.84 and 0.72; at 0.02 m 0.92 / 0.79 and 0.72; at 0.015 m 0.94 / 0.61 and 0.64.
pub const MASK_MAX_SIGMA_M: f32 = 0.02;
pub use super::scene::MASK_ALPHA;

/// A box's centre and yaw as a pose.
pub fn box_pose(b: &OrientedBox) -> Pose {
    let half_yaw = b.yaw / 2.0;
    Pose {
        position: Point {
            x: b.centre.x,
            y: b.centre.y,
            z: b.centre.z,
        },
        orientation: Quaternion {
            x: 0.0,
            y: 0.0,
            z: half_yaw.sin(),
            w: half_yaw.cos(),
        },
    }
}

/// The gravity-aligned box a pose (centre, yaw about z) and size describe: [`box_pose`]'s inverse.
pub fn pose_box(pose: &Pose, size: &Vector3) -> OrientedBox {
    let (p, q) = (&pose.position, &pose.orientation);
    OrientedBox {
        centre: glam::DVec3::new(p.x, p.y, p.z),
        size: glam::DVec3::new(size.x, size.y, size.z),
        yaw: 2.0 * q.z.atan2(q.w),
    }
}

pub fn bounding_box(b: &OrientedBox) -> BoundingBox3D {
    BoundingBox3D {
        center: box_pose(b),
        size: Vector3 {
            x: b.size.x,
            y: b.size.y,
            z: b.size.z,
        },
    }
}

/// Numeric instance id of `inst_000042` (42); 0 when the id has another form.
pub fn numeric_id(id: &str) -> u32 {
    id.rsplit('_')
        .next()
        .and_then(|n| n.parse().ok())
        .unwrap_or(0)
}

/// Gaussians as a PointCloud2 in `frame_id`: x, y, z, rgb (packed as PCL does) and instance_id.
pub fn instance_cloud(frame_id: &str, stamp: Time, instances: &[(u32, &Gaussians)]) -> PointCloud2 {
    const STEP: u32 = 20;
    let field = |name: &str, offset: u32, datatype: u8| PointField {
        name: name.into(),
        offset,
        datatype,
        count: 1,
    };
    let points: usize = instances.iter().map(|(_, g)| g.len()).sum();
    let mut data = Vec::with_capacity(points * STEP as usize);
    for (id, g) in instances {
        for (m, c) in g.means.iter().zip(&g.colors) {
            for v in [m.x, m.y, m.z] {
                data.extend_from_slice(&v.to_le_bytes());
            }
            let byte = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u32;
            let rgb = (byte(c.x) << 16) | (byte(c.y) << 8) | byte(c.z);
            data.extend_from_slice(&rgb.to_le_bytes());
            data.extend_from_slice(&id.to_le_bytes());
        }
    }
    PointCloud2 {
        header: Header {
            stamp,
            frame_id: frame_id.into(),
        },
        height: 1,
        width: points as u32,
        fields: vec![
            field("x", 0, PointField::FLOAT32),
            field("y", 4, PointField::FLOAT32),
            field("z", 8, PointField::FLOAT32),
            field("rgb", 12, PointField::FLOAT32),
            field("instance_id", 16, PointField::UINT32),
        ],
        is_bigendian: false,
        point_step: STEP,
        row_step: STEP * points as u32,
        data,
        is_dense: true,
    }
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

pub fn mono16(header: Header, w: u32, h: u32, labels: &[u16]) -> Image {
    Image {
        header,
        height: h,
        width: w,
        encoding: "mono16".into(),
        is_bigendian: 0,
        step: w * 2,
        data: labels.iter().flat_map(|v| v.to_le_bytes()).collect(),
    }
}

/// The map's points around the instances `ids` of `scene`'s map, for masks cut by measured depth.
fn answer_volume(scene: &ReferScene, ids: &[String]) -> Option<AnswerVolume> {
    let instances: Vec<&Gaussians> = scene.map.instances.iter().map(|i| &i.gaussians).collect();
    let chosen: Vec<usize> = ids
        .iter()
        .filter_map(|id| scene.map.instances.iter().position(|i| &i.id == id))
        .collect();
    AnswerVolume::new(&instances, &chosen)
}

/// The answer's labels in the snapshot's `k`-th keyframe: at the sensor's resolution, cut by its
/// depth, where the snapshot kept it; otherwise its splats at the keyframe's.
fn keyframe_labels<'s>(
    scene: &'s ReferScene,
    k: usize,
    keyframe: &'s Keyframe,
    answer: &[&Gaussians],
    volume: Option<&AnswerVolume>,
) -> (&'s Keyframe, Vec<u16>) {
    let scene_depth = scene.depths.get(k).map_or(&[][..], Vec::as_slice);
    match scene.measured.get(k).and_then(Option::as_ref) {
        Some(m) => {
            let size = |kf: &Keyframe| (kf.camera.width as usize, kf.camera.height as usize);
            let reference = resampled(scene_depth, size(keyframe), size(&m.keyframe));
            let measured = Some((m.depth.as_slice(), m.noise_at_1m));
            let labels = answer_labels(answer, volume, &m.keyframe, measured, &reference);
            (&m.keyframe, labels)
        }
        None => (keyframe, label_image(answer, keyframe, scene_depth)),
    }
}

/// The `Refer` response for `answer` on `scene`; `gaussians` are the chosen instances' (in the
/// answer's order, from the live map), `novel` an extra view to render masks into.
pub fn response(
    answer: &Answer,
    scene: &ReferScene,
    gaussians: &[Gaussians],
    world_frame: &str,
    novel: Option<&Keyframe>,
) -> ReferResponse {
    let chosen: Vec<&super::ReferNode> = answer
        .chosen
        .iter()
        .map(|c| &scene.nodes[c.index])
        .collect();
    let ids: Vec<String> = chosen.iter().map(|n| n.id.clone()).collect();
    let refs: Vec<&Gaussians> = gaussians.iter().collect();
    let stamp = scene
        .keyframes
        .first()
        .map_or(Time::default(), |k| Time::from_nanos(k.stamp_nanos));
    let cloud_items: Vec<(u32, &Gaussians)> = chosen
        .iter()
        .zip(gaussians)
        .map(|(n, g)| (numeric_id(&n.id), g))
        .collect();
    let volume = answer_volume(scene, &ids);
    let mut view_masks: Vec<InstanceMasks> = scene
        .keyframes
        .iter()
        .enumerate()
        .map(|(k, kf)| keyframe_labels(scene, k, kf, &refs, volume.as_ref()))
        .chain(novel.map(|kf| (kf, label_image(&refs, kf, &[]))))
        .map(|(kf, labels)| InstanceMasks {
            header: Header {
                stamp: Time::from_nanos(kf.stamp_nanos),
                frame_id: String::new(),
            },
            camera: String::new(),
            mask: mono16(
                Header {
                    stamp: Time::from_nanos(kf.stamp_nanos),
                    frame_id: String::new(),
                },
                kf.camera.width,
                kf.camera.height,
                &labels,
            ),
            instance_ids: ids.clone(),
        })
        .collect();
    // A view where none of the answer is seen carries nothing.
    view_masks.retain(|m| m.mask.data.iter().any(|b| *b != 0));
    let message = if answer.chosen.is_empty() {
        "no instance fits".to_owned()
    } else {
        format!("{} instance(s)", answer.chosen.len())
    };
    ReferResponse {
        success: !answer.chosen.is_empty(),
        message,
        instance_ids: ids,
        confidences: answer.chosen.iter().map(|c| c.confidence).collect(),
        poses: chosen.iter().map(|n| box_pose(&n.bbox)).collect(),
        boxes: chosen.iter().map(|n| bounding_box(&n.bbox)).collect(),
        target_cloud: instance_cloud(world_frame, stamp, &cloud_items),
        view_masks,
        candidates: answer
            .candidates
            .iter()
            .map(|c| Candidate {
                id: c.id.clone(),
                label: c.label.clone(),
                score: c.score,
                semantic_score: c.semantic,
                geometric_score: c.geometric,
                visibility_score: c.visibility,
            })
            .collect(),
        reasoner_used: answer.reasoner_used.clone(),
        trace: answer.trace.clone(),
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::recon::camera::Camera;
    use crate::recon::Rigid;
    use glam::{Quat, Vec3};

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

    fn keyframe() -> Keyframe {
        Keyframe {
            stamp_nanos: 0,
            camera: Camera::from_fov(64, 48, 1.2).unwrap(),
            world_from_camera: Rigid::default(),
        }
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

    #[test]
    fn clouds_carry_every_point_with_its_instance_id() {
        let g = wall(0.0, 0.04, 1.0);
        let cloud = instance_cloud("map", Time::default(), &[(42, &g), (7, &g)]);
        assert_eq!(cloud.width as usize, 2 * g.len());
        assert_eq!(cloud.data.len(), (cloud.point_step * cloud.width) as usize);
        let id_at = |i: usize| {
            let o = i * cloud.point_step as usize + 16;
            u32::from_le_bytes(cloud.data[o..o + 4].try_into().unwrap())
        };
        assert_eq!(id_at(0), 42);
        assert_eq!(id_at(g.len()), 7);
        assert_eq!(numeric_id("inst_000042"), 42);
        assert_eq!(numeric_id("garbage"), 0);
    }
}
