//! The benchmark's expressions and the geometry the generator decides relations on: what the
//! relations mean lives in `groupforward-relations`, which the node's reasoner reads too.

use serde::{Deserialize, Serialize};

pub use groupforward_relations::{
    above_margin, bearing, between_margin, color_distance, color_name, front_margin, left_margin,
    on_margin, Geometry, PairMargin, Relation, ViewPose, BETWEEN_CLEARANCE_M, CLOSEST_GAP_M,
    COLOR_PALETTE, DEPTH_GAP_M, DIRECTION_MARGIN_DEG, SIZE_RATIO, SUPPORT_CONTACT_M,
    VERTICAL_SEPARATION_M,
};

use crate::library;
use crate::render::PlacedObject;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Expression {
    pub text: String,
    pub relation: Relation,
    /// Instance ids the expression means (sorted); `cardinality` = their number.
    pub targets: Vec<u16>,
    pub cardinality: usize,
    /// The targets' class ("" for function phrases, which name no class).
    pub target_class: String,
    /// Instances of the anchor classes the relation is about.
    pub anchors: Vec<u16>,
    /// Objects of the target's class that are not targets (ReferIt3D "hard": more than 2).
    pub distractors: usize,
    pub view_dependent: bool,
    pub view: Option<ViewPose>,
}

/// The relation geometry of a placed object: its bounds, its own size, class name and colour.
pub fn geometry(object: &PlacedObject) -> Geometry {
    let (lo, hi) = object.bounds();
    let class = library::classes()
        .into_iter()
        .find(|c| c.id == object.class_id)
        .map_or("object", |c| c.name);
    Geometry {
        id: object.instance_id,
        class,
        lo,
        hi,
        extent: object.oriented_extent().map_or(hi - lo, |(_, size)| size),
        color: object.color,
    }
}

pub fn plural(class: &str) -> String {
    match class {
        "box" => "boxes".into(),
        "bookshelf" => "bookshelves".into(),
        other => format!("{other}s"),
    }
}
