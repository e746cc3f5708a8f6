//! An answer as the `Refer` service returns it: per chosen instance its pose and gravity-aligned
//! box, its Gaussians as a PointCloud2 with an `instance_id` field, and its masks rendered into
//! the snapshot's keyframes (and into the request's view, if one was given; [`super::masks`]).

use groupforward_msgs::builtin_interfaces::Time;
use groupforward_msgs::geometry_msgs::{Point, Pose, Quaternion, Vector3};
use groupforward_msgs::gf_msgs::{Candidate, InstanceMasks, ReferResponse};
use groupforward_msgs::sensor_msgs::{Image, PointCloud2, PointField};
use groupforward_msgs::std_msgs::Header;
use groupforward_msgs::vision_msgs::BoundingBox3D;

use rayon::prelude::*;

use super::masks::{answer_volume, keyframe_labels, label_image};
use super::scene::ReferScene;
use super::Answer;
use crate::frame::Keyframe;
use crate::recon::boxes::OrientedBox;
use crate::recon::gaussians::Gaussians;

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
    // The views one per thread: each is a pass over a sensor image, the bulk of an answer.
    let in_views: Vec<(&Keyframe, Vec<u16>)> = scene
        .keyframes
        .par_iter()
        .enumerate()
        .map(|(k, kf)| keyframe_labels(scene, k, kf, &refs, volume.as_ref()))
        .collect();
    let mut view_masks: Vec<InstanceMasks> = in_views
        .into_iter()
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
        let count = format!("{} instance(s)", answer.chosen.len());
        match &answer.note {
            Some(note) => format!("{count}; {note}"),
            None => count,
        }
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
mod tests {
    use super::*;
    use crate::refer::masks::tests::wall;

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
