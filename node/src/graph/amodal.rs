//! Objects seen from one side, away from any wall: a chair seen from behind is its backrest, a
//! monitor its screen, a sofa its front, and the box fitted to those points is a few centimetres
//! deep (3D IoU with the object near zero; `eval map` traces most such losses to this). Where the
//! wall completion ([`super::walls`]) has no wall to read, the object's name does: the box is
//! extended along its thin axis, away from where the cameras that saw it stood, to the depth
//! objects of that name typically have (its class prior in the vocabulary file,
//! [`crate::group::vocabulary::ClassPriors`]). A size prior, so only for names with one, and only
//! for boxes much thinner than that depth: a box already deep enough is never changed.

use glam::{DVec2, DVec3, Vec3};

use crate::recon::boxes::OrientedBox;

/// A box is extended only when it is thinner than this share of the typical depth.
pub const THIN_SHARE: f64 = 0.35;
/// Its face (the wide horizontal side and the height) at least this large: smaller pieces are
/// fragments, not an object's side.
pub const MIN_FACE_M: f64 = 0.15;
/// The viewpoint must lie at least this far off the face's plane (m) to tell its sides apart.
const MIN_VIEW_OFFSET_M: f64 = 0.1;

/// `fitted` extended along its thin horizontal axis, away from `viewpoint`, to `depth`, when it
/// is a face of an object of that depth seen from one side (see the module notes); otherwise
/// `fitted` as it is.
pub fn complete_away_from(fitted: OrientedBox, viewpoint: Vec3, depth: f64) -> OrientedBox {
    let size = fitted.size;
    let viewpoint = viewpoint.as_dvec3();
    if !(fitted.centre.is_finite() && size.is_finite() && viewpoint.is_finite() && depth > 0.0) {
        return fitted;
    }
    let (thin, wide) = (size.x.min(size.y), size.x.max(size.y));
    if thin >= THIN_SHARE * depth || wide < MIN_FACE_M || size.z < MIN_FACE_M {
        return fitted;
    }
    let normal = thin_axis(&fitted);
    let offset = (fitted.centre - viewpoint).truncate().dot(normal);
    if offset.abs() < MIN_VIEW_OFFSET_M {
        return fitted;
    }
    // The seen face stays where it is; the box grows behind it, on the far side from the viewer.
    let away = normal * offset.signum();
    deepened(fitted, away * (depth - thin) / 2.0, depth)
}

/// The unit ground-plane axis along `fitted`'s thinner horizontal side (a face's normal).
fn thin_axis(fitted: &OrientedBox) -> DVec2 {
    let (c, s) = (fitted.yaw.cos(), fitted.yaw.sin());
    if fitted.size.x <= fitted.size.y {
        DVec2::new(c, s)
    } else {
        DVec2::new(-s, c)
    }
}

/// `fitted` extended along its thin horizontal axis toward `viewpoint`, to `depth`: the face
/// seen is the object's far side (its back against something), the rest stands in front of it.
/// The same conditions as [`complete_away_from`]; otherwise `fitted` as it is.
pub fn complete_toward(fitted: OrientedBox, viewpoint: Vec3, depth: f64) -> OrientedBox {
    // The viewpoint mirrored through the face's vertical plane: away from it is toward the viewer.
    let normal = thin_axis(&fitted);
    let v = viewpoint.as_dvec3();
    let offset = (v - fitted.centre).truncate().dot(normal);
    let mirrored = v - (normal * (2.0 * offset)).extend(0.0);
    complete_away_from(fitted, mirrored.as_vec3(), depth)
}

/// Objects that stand on the floor (a class prior, `stands_on_floor` in the vocabulary file): a
/// chair seen over a table is its backrest, a bed seen from across the room its mattress, and the
/// box fitted to those points floats, its 3D IoU with the object small.
/// A box whose bottom is this far above the floor or less already stands on it.
pub const RAISED_M: f64 = 0.2;
/// Boxes whose top is higher than this above the floor are left alone: no furniture of these
/// names is that tall, so the name or the floor is wrong.
pub const MAX_STANDING_TOP_M: f64 = 2.2;

/// `fitted` extended down to `floor` when it floats above it (its bottom more than
/// [`RAISED_M`] up, its top at most [`MAX_STANDING_TOP_M`]): the lower part of an object that
/// stands on the floor, hidden from every view that saw it. Otherwise `fitted` as it is.
pub fn down_to_floor(fitted: OrientedBox, floor: f64) -> OrientedBox {
    if !(fitted.centre.is_finite() && fitted.size.is_finite() && floor.is_finite()) {
        return fitted;
    }
    let (bottom, top) = (
        fitted.centre.z - fitted.size.z / 2.0,
        fitted.centre.z + fitted.size.z / 2.0,
    );
    if bottom - floor <= RAISED_M || top - floor > MAX_STANDING_TOP_M {
        return fitted;
    }
    let mut standing = fitted;
    standing.size.z = top - floor;
    standing.centre.z = (top + floor) / 2.0;
    standing
}

/// `fitted` with its thinner horizontal side `extent` long and its centre moved by `shift` in
/// the ground plane: a face completed to the object behind it.
pub(super) fn deepened(fitted: OrientedBox, shift: DVec2, extent: f64) -> OrientedBox {
    let moved = fitted.centre.truncate() + shift;
    let mut completed = fitted;
    completed.centre = DVec3::new(moved.x, moved.y, fitted.centre.z);
    if fitted.size.x <= fitted.size.y {
        completed.size.x = extent;
    } else {
        completed.size.y = extent;
    }
    completed
}

/// The class name and ground-truth box of every object, room by room, in the first 200 scenes
/// of the simulator's `train` split (the rooms the models were trained on): what the fold
/// thresholds in [`super::fusion`] and the floor patch height are checked against (the class
/// priors of the default vocabulary are measured there by `groupforward sim vocabulary`).
#[cfg(test)]
pub(crate) fn training_rooms() -> Vec<Vec<(&'static str, OrientedBox)>> {
    use groupforward_sim::procedural::{generate, Split};
    use groupforward_sim::simulation::Simulation;
    let classes = groupforward_sim::library::classes();
    (0..200)
        .map_while(|index| generate(Split::Train, index))
        .map(|file| {
            let sim = Simulation::new(file).expect("a training scene loads");
            sim.scene
                .objects
                .iter()
                .filter_map(|object| {
                    let class = classes.iter().find(|c| c.id == object.class_id)?;
                    let (centre, size) = object.oriented_extent()?;
                    let yaw = object.yaw;
                    Some((class.name, OrientedBox { centre, size, yaw }.canonical()))
                })
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A chair's backrest seen from behind: 0.45 m wide, 3 cm deep, its normal along y.
    fn backrest(yaw: f64) -> OrientedBox {
        OrientedBox {
            centre: DVec3::new(1.0, 2.0, 0.5),
            size: DVec3::new(0.45, 0.03, 1.0),
            yaw,
        }
    }

    #[test]
    fn a_face_seen_from_one_side_grows_away_from_the_viewer() {
        for yaw in [0.0, 0.7, -2.0] {
            let face = backrest(yaw);
            let normal = DVec2::new(-yaw.sin(), yaw.cos());
            // The viewer stands 2 m in front of the face, on the normal's negative side.
            let viewer = face.centre - (normal * 2.0).extend(0.0);
            let completed = complete_away_from(face, viewer.as_vec3(), 0.45);
            assert!((completed.size.y - 0.45).abs() < 1e-9, "{completed:?}");
            assert_eq!((completed.size.x, completed.size.z), (0.45, 1.0));
            // The seen face (nearest the viewer) did not move; the rest lies behind it.
            let near =
                |b: &OrientedBox| (b.centre - viewer).truncate().dot(normal) - b.size.y / 2.0;
            assert!((near(&completed) - near(&face)).abs() < 1e-9);
            assert!((completed.centre - face.centre).truncate().dot(normal) > 0.2);
            // Toward the viewer instead: the same box on the viewer's side of the face.
            let toward = complete_toward(face, viewer.as_vec3(), 0.45);
            assert!((toward.size - completed.size).length() < 1e-9, "{toward:?}");
            assert!((toward.centre - face.centre).truncate().dot(normal) < -0.2);
            let far = |b: &OrientedBox| (b.centre - viewer).truncate().dot(normal) + b.size.y / 2.0;
            assert!((far(&toward) - far(&face)).abs() < 1e-9);
        }
    }

    #[test]
    fn deep_boxes_small_pieces_and_a_viewer_in_the_plane_keep_their_box() {
        let face = backrest(0.0);
        let viewer = Vec3::new(1.0, 0.0, 1.2);
        let deep = OrientedBox {
            size: DVec3::new(0.45, 0.3, 1.0),
            ..face
        };
        assert_eq!(complete_away_from(deep, viewer, 0.45), deep);
        let piece = OrientedBox {
            size: DVec3::new(0.1, 0.02, 1.0),
            ..face
        };
        assert_eq!(complete_away_from(piece, viewer, 0.45), piece);
        let beside = Vec3::new(3.0, 2.0, 1.2);
        assert_eq!(complete_away_from(face, beside, 0.45), face);
    }

    #[test]
    fn degenerate_boxes_and_viewpoints_stay_finite_and_unchanged() {
        let face = backrest(0.0);
        for viewer in [Vec3::NAN, Vec3::new(f32::INFINITY, 0.0, 0.0)] {
            assert_eq!(complete_away_from(face, viewer, 0.45), face);
            assert_eq!(complete_toward(face, viewer, 0.45), face);
        }
        assert_eq!(complete_away_from(face, Vec3::ZERO, 0.0), face);
        let flat = OrientedBox {
            size: DVec3::ZERO,
            ..face
        };
        assert_eq!(complete_away_from(flat, Vec3::ZERO, 0.45), flat);
        let nan = OrientedBox {
            centre: DVec3::NAN,
            ..face
        };
        let kept = complete_away_from(nan, Vec3::ZERO, 0.45);
        assert!(kept.centre.x.is_nan() && kept.size == face.size);
    }

    #[test]
    fn a_chair_seen_over_a_table_reaches_down_to_the_floor() {
        // Its backrest, 0.5 to 1.0 m up: the seat and legs were behind the table.
        let seen = OrientedBox {
            centre: DVec3::new(1.0, 2.0, 0.75),
            size: DVec3::new(0.45, 0.03, 0.5),
            yaw: 0.3,
        };
        let standing = down_to_floor(seen, 0.02);
        assert!((standing.size.z - 0.98).abs() < 1e-9, "{standing:?}");
        assert!((standing.centre.z - 0.51).abs() < 1e-9);
        assert_eq!(standing.centre.truncate(), seen.centre.truncate());
        assert_eq!(
            (standing.size.x, standing.size.y, standing.yaw),
            (0.45, 0.03, 0.3)
        );
    }

    #[test]
    fn standing_tall_and_degenerate_boxes_keep_their_box() {
        let on_floor = OrientedBox {
            centre: DVec3::new(1.0, 2.0, 0.55),
            ..backrest(0.0)
        };
        assert_eq!(down_to_floor(on_floor, 0.0), on_floor);
        let high = OrientedBox {
            centre: DVec3::new(1.0, 2.0, 2.0),
            ..backrest(0.0)
        };
        assert!(high.centre.z + high.size.z / 2.0 > MAX_STANDING_TOP_M);
        assert_eq!(down_to_floor(high, 0.0), high);
        let seen = OrientedBox {
            centre: DVec3::new(1.0, 2.0, 0.8),
            ..backrest(0.0)
        };
        assert_eq!(down_to_floor(seen, f64::NAN), seen);
        let nan = OrientedBox {
            centre: DVec3::NAN,
            ..seen
        };
        let kept = down_to_floor(nan, 0.0);
        assert!(kept.centre.x.is_nan() && kept.size == seen.size);
        let flat = OrientedBox {
            size: DVec3::ZERO,
            ..seen
        };
        let grown = down_to_floor(flat, 0.0);
        assert!(grown.size.is_finite() && grown.centre.is_finite() && grown.size.z > 0.4);
    }

    /// `measure` of the ground-truth box of every object in the first 200 scenes of the
    /// simulator's `train` split (the rooms the models were trained on), by class name.
    fn training_boxes(
        measure: impl Fn(&OrientedBox) -> f64,
    ) -> std::collections::HashMap<&'static str, Vec<f64>> {
        let mut measured: std::collections::HashMap<&str, Vec<f64>> = Default::default();
        for (name, b) in training_rooms().into_iter().flatten() {
            measured.entry(name).or_default().push(measure(&b));
        }
        measured
    }

    #[test]
    fn every_object_of_the_training_rooms_rises_well_above_the_floor_patch_height() {
        let tops = training_boxes(|b| b.centre.z + b.size.z / 2.0);
        let lowest = tops
            .values()
            .flatten()
            .copied()
            .fold(f64::INFINITY, f64::min);
        assert!(
            lowest > 2.0 * super::super::walls::FLOOR_TOP_M,
            "an object's top {lowest:.3} m up"
        );
    }
}
