//! Referring expressions generated from ground truth, for benchmark sets.
//!
//! Templates cover every relation of the Sr3D taxonomy the node answers (closest / farthest,
//! above / below, on / supporting, left / right / front / behind in a named view, between),
//! superlatives, colour attributes, function phrases, plural cardinality and two-hop anchors
//! ("the table closest to the chair farthest from the bed"). An expression is
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
    builder.two_hops();
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

/// A scene's benchmark as an observer of its trajectory can know it ([`observed_expressions`]).
#[derive(Debug, Clone, PartialEq)]
pub struct ObservedBenchmark {
    /// Decided over the observed objects alone (a superlative or relation over that set).
    pub answerable: Vec<Expression>,
    /// About a class no observed object has (a function none serves): right only as a refusal.
    pub refusals: Vec<Expression>,
    /// Decided over every object, seen or not: the benchmark before it knew what was seen.
    pub every_object: Vec<Expression>,
}

/// A scene's benchmark as an observer of its trajectory can know it: `observed` holds the instance
/// ids the trajectory saw well enough (the evaluation's pixel floor). The refusal tests are the
/// expressions over every object whose targets were all never observed and of a class no observed
/// object has, and whose text the observed objects do not also generate. A system that saw the
/// room can only answer those with "not seen".
pub fn observed_expressions(
    file: &crate::scene::SceneFile,
    observed: &[u16],
) -> Result<ObservedBenchmark, crate::scene::SceneError> {
    let scene = file.build()?;
    let half_fov = file.cameras.first().map_or(45.0, |c| c.fov_x_deg / 2.0);
    let views = trajectory_views(file, 20);
    let seen = Scene {
        room_size: scene.room_size,
        floor_color: scene.floor_color,
        wall_color: scene.wall_color,
        objects: scene
            .objects
            .iter()
            .filter(|o| observed.contains(&o.instance_id))
            .cloned()
            .collect(),
    };
    let observed_classes: std::collections::HashSet<&str> =
        seen.objects.iter().map(|o| geometry(o).class).collect();
    let answerable = generate(&seen, &views, half_fov);
    let every_object = generate(&scene, &views, half_fov);
    let texts: std::collections::HashSet<&str> =
        answerable.iter().map(|e| e.text.as_str()).collect();
    let refusals = every_object
        .iter()
        .filter(|e| {
            !e.targets.is_empty()
                && e.targets.iter().all(|t| !observed.contains(t))
                && !observed_classes.contains(e.target_class.as_str())
                && !texts.contains(e.text.as_str())
        })
        .cloned()
        .collect();
    Ok(ObservedBenchmark {
        answerable,
        refusals,
        every_object,
    })
}
