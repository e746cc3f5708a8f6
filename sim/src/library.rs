//! The object library: indoor classes with ScanNet-like names, each built from analytic primitives
//! (boxes and vertical cylinders, in the object's frame: z up, base on z = 0), with a nominal size,
//! a plausible colour, a short description and affordances.

use glam::DVec3;

/// A primitive in the object's frame (metres at scale 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Primitive {
    /// Axis-aligned box: centre and half extents.
    Box { center: [f64; 3], half: [f64; 3] },
    /// Vertical cylinder: centre, radius and half height.
    Cylinder {
        center: [f64; 3],
        radius: f64,
        half_height: f64,
    },
}

impl Primitive {
    /// Centre and half extents of the part's axis-aligned box, in the object's frame.
    pub fn extent(&self) -> (DVec3, DVec3) {
        match *self {
            Primitive::Box { center, half } => (center.into(), half.into()),
            Primitive::Cylinder {
                center,
                radius,
                half_height,
            } => (center.into(), DVec3::new(radius, radius, half_height)),
        }
    }
}

/// A horizontal surface of an object that can carry other objects (a table top, a shelf), in the
/// object's frame at scale 1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surface {
    /// Centre (x, y) and half extents of the usable rectangle.
    pub center: [f64; 2],
    pub half: [f64; 2],
    /// Height of the surface above the object's base.
    pub z: f64,
    /// Free height above the surface (the next shelf, or unbounded on top).
    pub clearance: f64,
}

/// Where an object of a class may stand: on the floor, or on another object's surface.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Placement {
    Floor,
    /// Small objects: on a surface of one of `supports`, or (if `floor_too`) on the floor.
    OnTopOf {
        supports: &'static [&'static str],
        floor_too: bool,
    },
}

/// One class of the library.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectClass {
    pub name: &'static str,
    /// 1-based class id; 0 is the room (walls and floor).
    pub id: u16,
    pub color: [f32; 3],
    pub description: &'static str,
    pub affordances: &'static [&'static str],
    pub parts: Vec<Primitive>,
    pub surfaces: &'static [Surface],
    pub placement: Placement,
}

/// Procedural scenes scale every object by a factor drawn from this range (the class's size range).
pub const SCALE_RANGE: (f64, f64) = (0.85, 1.15);

const UNBOUNDED: f64 = f64::INFINITY;

const fn surface(cx: f64, cy: f64, hx: f64, hy: f64, z: f64, clearance: f64) -> Surface {
    Surface {
        center: [cx, cy],
        half: [hx, hy],
        z,
        clearance,
    }
}

/// Surfaces and placement rules per class name (classes not listed carry nothing and stand on the
/// floor).
fn support_rules(name: &str) -> (&'static [Surface], Placement) {
    const TABLE: &[Surface] = &[surface(0.0, 0.0, 0.56, 0.36, 0.75, UNBOUNDED)];
    const DESK: &[Surface] = &[surface(0.0, 0.0, 0.66, 0.31, 0.74, UNBOUNDED)];
    const CABINET: &[Surface] = &[surface(0.0, 0.0, 0.36, 0.21, 1.8, UNBOUNDED)];
    const BED: &[Surface] = &[surface(0.0, 0.3, 0.75, 0.6, 0.5, UNBOUNDED)];
    const SOFA: &[Surface] = &[surface(0.0, 0.07, 0.95, 0.36, 0.44, UNBOUNDED)];
    // Shelves at 0.62 and 1.22 m (boards 0.04 m thick, 0.56 m apart) and the top at 1.8 m.
    const BOOKSHELF: &[Surface] = &[
        surface(0.0, -0.01, 0.42, 0.13, 0.62, 0.54),
        surface(0.0, -0.01, 0.42, 0.13, 1.22, 0.54),
        surface(0.0, 0.0, 0.42, 0.15, 1.8, UNBOUNDED),
    ];
    const FRIDGE: &[Surface] = &[surface(0.0, 0.0, 0.3, 0.28, 1.8, UNBOUNDED)];
    let on = |supports, floor_too| Placement::OnTopOf {
        supports,
        floor_too,
    };
    match name {
        "table" => (TABLE, Placement::Floor),
        "desk" => (DESK, Placement::Floor),
        "cabinet" => (CABINET, Placement::Floor),
        "bed" => (BED, Placement::Floor),
        "sofa" => (SOFA, Placement::Floor),
        "bookshelf" => (BOOKSHELF, Placement::Floor),
        "refrigerator" => (FRIDGE, Placement::Floor),
        "lamp" => (&[], on(&["table", "desk", "cabinet"][..], true)),
        "monitor" => (&[], on(&["desk", "table"][..], false)),
        "box" => (
            &[],
            on(&["bookshelf", "table", "cabinet", "refrigerator"][..], true),
        ),
        "pillow" => (&[], on(&["bed", "sofa"][..], false)),
        "plant" => (&[], on(&["table", "desk"][..], true)),
        _ => (&[], Placement::Floor),
    }
}

fn cuboid(cx: f64, cy: f64, cz: f64, hx: f64, hy: f64, hz: f64) -> Primitive {
    Primitive::Box {
        center: [cx, cy, cz],
        half: [hx, hy, hz],
    }
}

fn cylinder(cx: f64, cy: f64, cz: f64, radius: f64, half_height: f64) -> Primitive {
    Primitive::Cylinder {
        center: [cx, cy, cz],
        radius,
        half_height,
    }
}

/// A table-like frame: a top of `w × d` at height `h` with four legs.
fn table_frame(w: f64, d: f64, h: f64, top: f64, leg: f64) -> Vec<Primitive> {
    let (x, y) = (w / 2.0 - leg, d / 2.0 - leg);
    let legs = (h - top) / 2.0;
    vec![
        cuboid(0.0, 0.0, h - top / 2.0, w / 2.0, d / 2.0, top / 2.0),
        cuboid(x, y, legs, leg, leg, legs),
        cuboid(-x, y, legs, leg, leg, legs),
        cuboid(x, -y, legs, leg, leg, legs),
        cuboid(-x, -y, legs, leg, leg, legs),
    ]
}

/// Every class, ids 1..=N in this order.
pub fn classes() -> Vec<ObjectClass> {
    let mut all = vec![
        (
            "chair",
            [0.55, 0.35, 0.2],
            "a chair with four legs and a backrest",
            &["sit on"][..],
            {
                let mut parts = table_frame(0.45, 0.45, 0.46, 0.05, 0.025);
                parts.push(cuboid(0.0, -0.2, 0.7, 0.225, 0.025, 0.22));
                parts
            },
        ),
        (
            "table",
            [0.6, 0.45, 0.3],
            "a dining table",
            &["put things on", "eat at"][..],
            table_frame(1.2, 0.8, 0.75, 0.04, 0.035),
        ),
        (
            "desk",
            [0.75, 0.75, 0.72],
            "a desk with a drawer block",
            &["work at", "put a computer on"][..],
            {
                let mut parts = table_frame(1.4, 0.7, 0.74, 0.04, 0.03);
                parts.push(cuboid(0.45, 0.0, 0.35, 0.2, 0.3, 0.35));
                parts
            },
        ),
        (
            "cabinet",
            [0.8, 0.8, 0.78],
            "a tall storage cabinet",
            &["store things in"][..],
            vec![cuboid(0.0, 0.0, 0.9, 0.4, 0.25, 0.9)],
        ),
        (
            "trash bin",
            [0.25, 0.3, 0.3],
            "a round trash bin",
            &["throw away rubbish"][..],
            vec![cylinder(0.0, 0.0, 0.3, 0.18, 0.3)],
        ),
        (
            "sink",
            [0.9, 0.9, 0.92],
            "a bathroom sink on a pedestal",
            &["wash hands"][..],
            vec![
                cylinder(0.0, 0.0, 0.4, 0.1, 0.4),
                cuboid(0.0, 0.0, 0.85, 0.3, 0.22, 0.08),
            ],
        ),
        (
            "bed",
            [0.85, 0.85, 0.95],
            "a double bed with a headboard",
            &["sleep on", "lie down on"][..],
            vec![
                cuboid(0.0, 0.0, 0.25, 0.8, 1.0, 0.25),
                cuboid(0.0, 1.0, 0.55, 0.8, 0.04, 0.55),
            ],
        ),
        (
            "sofa",
            [0.3, 0.4, 0.6],
            "a three-seat sofa",
            &["sit on", "lie down on"][..],
            vec![
                cuboid(0.0, 0.0, 0.22, 1.0, 0.45, 0.22),
                cuboid(0.0, -0.38, 0.6, 1.0, 0.07, 0.3),
            ],
        ),
        (
            "lamp",
            [0.95, 0.9, 0.6],
            "a table lamp with a shade",
            &["give light"][..],
            vec![
                cylinder(0.0, 0.0, 0.02, 0.08, 0.02),
                cylinder(0.0, 0.0, 0.2, 0.012, 0.18),
                cylinder(0.0, 0.0, 0.42, 0.12, 0.08),
            ],
        ),
        (
            "bookshelf",
            [0.5, 0.32, 0.18],
            "an open bookshelf",
            &["keep books on"][..],
            vec![
                cuboid(0.0, 0.15, 0.9, 0.45, 0.02, 0.9),
                cuboid(0.0, 0.0, 0.02, 0.45, 0.15, 0.02),
                cuboid(0.0, 0.0, 0.6, 0.45, 0.15, 0.02),
                cuboid(0.0, 0.0, 1.2, 0.45, 0.15, 0.02),
                cuboid(0.0, 0.0, 1.78, 0.45, 0.15, 0.02),
            ],
        ),
        (
            "toilet",
            [0.95, 0.95, 0.95],
            "a toilet with a cistern",
            &["use the toilet"][..],
            vec![
                cylinder(0.0, 0.0, 0.2, 0.2, 0.2),
                cuboid(0.0, 0.22, 0.6, 0.2, 0.08, 0.2),
            ],
        ),
        (
            "refrigerator",
            [0.88, 0.9, 0.92],
            "a tall refrigerator",
            &["keep food cold"][..],
            vec![cuboid(0.0, 0.0, 0.9, 0.35, 0.33, 0.9)],
        ),
        (
            "monitor",
            [0.1, 0.1, 0.12],
            "a computer monitor on a stand",
            &["look at a screen"][..],
            vec![
                cuboid(0.0, 0.0, 0.01, 0.1, 0.08, 0.01),
                cuboid(0.0, 0.0, 0.1, 0.02, 0.02, 0.09),
                cuboid(0.0, 0.0, 0.33, 0.28, 0.02, 0.17),
            ],
        ),
        (
            "plant",
            [0.2, 0.55, 0.25],
            "a potted plant",
            &["water"][..],
            vec![
                cylinder(0.0, 0.0, 0.15, 0.14, 0.15),
                cylinder(0.0, 0.0, 0.55, 0.22, 0.25),
            ],
        ),
        (
            "box",
            [0.7, 0.55, 0.35],
            "a cardboard box",
            &["store things in", "carry"][..],
            vec![cuboid(0.0, 0.0, 0.15, 0.2, 0.15, 0.15)],
        ),
        (
            "pillow",
            [0.9, 0.85, 0.8],
            "a pillow",
            &["rest the head on"][..],
            vec![cuboid(0.0, 0.0, 0.06, 0.3, 0.2, 0.06)],
        ),
    ];
    all.drain(..)
        .enumerate()
        .map(|(i, (name, color, description, affordances, parts))| {
            let (surfaces, placement) = support_rules(name);
            ObjectClass {
                name,
                id: i as u16 + 1,
                color,
                description,
                affordances,
                parts,
                surfaces,
                placement,
            }
        })
        .collect()
}

/// A class by name.
pub fn class(name: &str) -> Option<ObjectClass> {
    classes().into_iter().find(|c| c.name == name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn library_has_the_required_classes_with_unique_ids_and_grounded_parts() {
        let all = classes();
        assert!(all.len() >= 16);
        for required in [
            "chair",
            "table",
            "desk",
            "cabinet",
            "trash bin",
            "sink",
            "bed",
            "sofa",
            "lamp",
            "bookshelf",
            "toilet",
            "refrigerator",
            "monitor",
            "plant",
            "box",
            "pillow",
        ] {
            assert!(class(required).is_some(), "{required}");
        }
        for (i, c) in all.iter().enumerate() {
            assert_eq!(c.id as usize, i + 1);
            assert!(!c.affordances.is_empty() && !c.description.is_empty());
            // Every class stands on the floor: its lowest part touches z = 0.
            let lowest = c
                .parts
                .iter()
                .map(|p| match p {
                    Primitive::Box { center, half } => center[2] - half[2],
                    Primitive::Cylinder {
                        center,
                        half_height,
                        ..
                    } => center[2] - half_height,
                })
                .fold(f64::INFINITY, f64::min);
            assert!(lowest.abs() < 1e-9, "{} starts at {lowest}", c.name);
            if let Placement::OnTopOf { supports, .. } = c.placement {
                for support in supports {
                    let s = class(support).unwrap_or_else(|| panic!("{support}"));
                    assert!(!s.surfaces.is_empty(), "{support} carries {}", c.name);
                }
            }
        }
    }

    #[test]
    fn every_surface_lies_on_top_of_a_part_of_its_object() {
        for c in classes() {
            for s in c.surfaces {
                let touching = c.parts.iter().any(|p| match *p {
                    Primitive::Box { center, half } => {
                        (center[2] + half[2] - s.z).abs() < 1e-9
                            && (s.center[0] - center[0]).abs() + s.half[0] <= half[0] + 1e-9
                            && (s.center[1] - center[1]).abs() + s.half[1] <= half[1] + 1e-9
                    }
                    Primitive::Cylinder { .. } => false,
                });
                assert!(touching, "{}: surface at z {} floats", c.name, s.z);
            }
        }
    }
}
