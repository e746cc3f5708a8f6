//! Referring expressions generated from ground truth, for benchmark sets.
//!
//! Templates cover every relation of the Sr3D taxonomy the node answers (closest / farthest,
//! above / below, on / supporting, left / right / front / behind in a named view, between),
//! superlatives, colour attributes, function phrases and plural cardinality. An expression is
//! kept only if exactly its targets satisfy it with a margin, using the thresholds ReferIt3D's
//! Sr3D generator uses: a 0.2 m gap for closest / farthest, 0.06 m vertical separation for above
//! / below, support touching within 0.15 m, 0.3 m clearance for between, 10° for view-dependent
//! directions. Every other object of the target's class must clearly fail.

mod relations;
mod templates;

pub use relations::{
    above_margin, bearing, between_margin, color_name, front_margin, geometry, left_margin,
    on_margin, plural, Expression, Geometry, Relation, ViewPose, BETWEEN_CLEARANCE_M,
    CLOSEST_GAP_M, COLOR_PALETTE, DEPTH_GAP_M, DIRECTION_MARGIN_DEG, SIZE_RATIO, SUPPORT_CONTACT_M,
    VERTICAL_SEPARATION_M,
};

use crate::render::Scene;
use templates::Builder;

/// Every unambiguous expression of `scene`; view-dependent ones in each of `views`
/// (`half_fov_deg`: half the horizontal field of view).
pub fn generate(scene: &Scene, views: &[ViewPose], half_fov_deg: f64) -> Vec<Expression> {
    let objects: Vec<Geometry> = scene.objects.iter().map(geometry).collect();
    let mut builder = Builder {
        objects: &objects,
        out: Vec::new(),
    };
    builder.class_and_cardinality();
    builder.distance_relations();
    builder.support_relations();
    builder.between();
    builder.superlatives();
    builder.colors();
    builder.functions();
    for view in views {
        builder.view_relations(*view, half_fov_deg);
    }
    builder.out
}

/// The viewpoints of a scene's benchmark: the first camera every `every` frames of the trajectory.
pub fn trajectory_views(file: &crate::scene::SceneFile, every: usize) -> Vec<ViewPose> {
    let Ok(poses) = file.robot_poses() else {
        return Vec::new();
    };
    let Some(camera) = file.cameras.first() else {
        return Vec::new();
    };
    poses
        .iter()
        .enumerate()
        .step_by(every.max(1))
        .map(|(frame, pose)| {
            let (rotation, position) = crate::scene::camera_pose(camera, pose);
            ViewPose::new(frame, rotation, position)
        })
        .collect()
}

/// A scene's benchmark expressions: view-independent ones once, view-dependent ones in views
/// every 20 frames.
pub fn scene_expressions(
    file: &crate::scene::SceneFile,
) -> Result<Vec<Expression>, crate::scene::SceneError> {
    let scene = file.build()?;
    let half_fov = file.cameras.first().map_or(45.0, |c| c.fov_x_deg / 2.0);
    Ok(generate(&scene, &trajectory_views(file, 20), half_fov))
}
