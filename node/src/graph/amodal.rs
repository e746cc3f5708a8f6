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
    length_axis(fitted, fitted.size.x <= fitted.size.y)
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
/// A box whose bottom is this far above the floor or less already stands on it: the floor's
/// height is read in 2 cm bands ([`crate::group::cleaning::floor_height`]). Furniture's lowest
/// centimetres are the ones the window leaves out (the floor slab around a table's feet is cut
/// away as support bleed), so tables and cabinets were fitted 0.1-0.18 m above the floor.
/// 0.02 against 0.05 and the 0.2 before it, paired, mean IoU: benchmark 7000-7019 +0.013 /
/// +0.008, 8000-8019 +0.011 / +0.006, `realistic` 7000-7019 +0.006 / +0.003, layouts 40-59
/// +0.009 / +0.006 (recall@0.5 +0.4 to +1.1 points at both, recall@0.25 and precision equal).
pub const RAISED_M: f64 = 0.02;
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
    reaching_down_to(fitted, floor)
}

/// `fitted` with its top kept and its bottom at `bottom`.
fn reaching_down_to(fitted: OrientedBox, bottom: f64) -> OrientedBox {
    let top = fitted.centre.z + fitted.size.z / 2.0;
    let mut reaching = fitted;
    reaching.size.z = top - bottom;
    reaching.centre.z = (top + bottom) / 2.0;
    reaching
}

/// Objects that rest on something other than the floor (a class prior, `typical_height_m` in the
/// vocabulary file): a lamp on a table is seen as its shade, its thin stand left out of every
/// window, and the box fitted to the shade floats 0.16-0.37 m above the lamp's bottom (benchmark
/// 12000-12019). A box shorter than this share of its name's typical height grows down. Checked
/// on benchmark 12600-12619 and layouts 560-579, which no setting was read from (recall@0.5 +0.6
/// / +1.1 points, nothing lost).
pub const RESTING_HEIGHT_SHARE: f64 = 0.8;

/// `fitted` grown down to `height` when it is shorter than [`RESTING_HEIGHT_SHARE`] of it, its
/// bottom no lower than `support` gives (the height of the surface under it; `-inf` when none was
/// seen; asked only for a box that may grow). Otherwise `fitted` as it is.
pub fn grown_down_to_rest(
    fitted: OrientedBox,
    height: f64,
    support: impl FnOnce() -> f64,
) -> OrientedBox {
    if !(fitted.centre.is_finite() && fitted.size.is_finite() && height.is_finite())
        || fitted.size.z >= RESTING_HEIGHT_SHARE * height
    {
        return fitted;
    }
    let top = fitted.centre.z + fitted.size.z / 2.0;
    let bottom = (top - height).max(support());
    if bottom >= top - fitted.size.z {
        return fitted;
    }
    reaching_down_to(fitted, bottom)
}

/// Objects seen in part along their length: a desk whose far end the camera never had in view, a
/// sofa half hidden behind a table. The box fitted to what was seen is a piece of the object
/// (`eval map` counts most of its fusion losses there). Where the box is much shorter than its
/// name's typical length, it grows to it along its length, but only where no view saw past its end
/// ([`crate::graph::Instance::seen_free`]: free space just beyond an end means the object ends
/// there) and no other instance's points stand (a neighbour in a row, a wall). A box at least this
/// share of the typical length along both sides (or, seen across its whole depth, along the other
/// side: [`is_seen_in_part`]) is left as it is. Read on benchmark 7000-7019, 8000-8019 and layouts
/// 0-59 (0.75 gained one object there, history.md); checked on benchmark 11200, 11400, 11600 and
/// layouts 320, 360 (20 scenes each), which no setting was read from.
pub const SEEN_IN_PART_SHARE: f64 = 0.6;
/// A box grows no closer than this (m) to a point that blocks it (one within its width and
/// height: a wall just behind it does not block it along its length). A choice: the spacing of
/// the probes ([`crate::graph::Instance::seen_free`]) past an end starts at 0.1 m.
const STOP_SHORT_M: f64 = 0.1;
/// The side across an object's length is within this factor of its name's typical depth. Read on
/// benchmark 8000-8019 (a trash bin named sofa, 0.4 m across, grew into a sofa without it) and
/// checked on the ranges [`SEEN_IN_PART_SHARE`] names.
const DEPTH_MARGIN: f64 = 1.5;
/// Two axes whose room makes up shares of their missing lengths this close have the same room (a
/// choice, not read off scenes).
const ROOM_SHARE_TIE: f64 = 0.05;
/// Growth under this (m) is none: the points' own rounding.
const MIN_GROWTH_M: f64 = 0.01;

/// `fitted` grown along its length to `length` where it is an object seen in part
/// ([`is_seen_in_part`]), each end no
/// further than the nearest of the `blocked` points beyond it (seen free, or another object's);
/// half the missing length on either end where both have room. Its length is the side along
/// which more of the missing length has room, or where both have as much, the side whose other
/// side is nearer the name's `depth` (the longer without one), so a desk seen across its width
/// grows along its length. Otherwise `fitted` as it is.
pub fn grown_to_length(
    fitted: OrientedBox,
    blocked: &[Vec3],
    length: f64,
    depth: Option<f64>,
) -> OrientedBox {
    let size = fitted.size;
    let depth = depth.filter(|d| *d > 0.0);
    if !(fitted.centre.is_finite() && size.is_finite() && is_seen_in_part(&fitted, length, depth)) {
        return fitted;
    }
    let growth = |along_x: bool| {
        // A face's thin side is its depth, the face completion's to grow, never its length.
        let (side, across) = if along_x {
            (size.x, size.y)
        } else {
            (size.y, size.x)
        };
        let face = depth.is_some_and(|d| side < THIN_SHARE * d && across > side);
        // The side across the length is the object's depth, seen whole more often than not: a
        // monitor's width is no depth (its screen's thickness is not its length), and a trash
        // bin named sofa is far shallower than any sofa.
        let no_depth =
            depth.is_some_and(|d| across > DEPTH_MARGIN * d || across < d / DEPTH_MARGIN);
        (!face && !no_depth).then(|| growth_along(&fitted, blocked, along_x, length))
    };
    let by_depth = match depth {
        Some(d) => (size.y / d).ln().abs() <= (size.x / d).ln().abs(),
        None => size.x >= size.y,
    };
    // The axis along which views saw less past the ends (more of the missing length has room);
    // where both have the same, the one whose other side is nearer the name's depth.
    let chosen = match (growth(true), growth(false)) {
        (Some(x), Some(y)) if (x.share - y.share).abs() >= ROOM_SHARE_TIE => {
            if x.share > y.share {
                x
            } else {
                y
            }
        }
        (Some(x), Some(y)) => {
            if by_depth {
                x
            } else {
                y
            }
        }
        (Some(only), None) | (None, Some(only)) => only,
        (None, None) => return fitted,
    };
    chosen.applied_to(fitted)
}

/// Whether `fitted` may be a piece of an object `length` long and `depth` deep
/// ([`SEEN_IN_PART_SHARE`]): both horizontal sides under that share of the length, or, seen
/// across its whole depth (its longer side nearer the depth than the length, within
/// [`DEPTH_MARGIN`] of it), the other side under that share (a bed seen as its foot end, 1.64 m
/// across and 0.76 m of its 2 m length: benchmark 8006). False for a length that is no positive
/// number.
pub fn is_seen_in_part(fitted: &OrientedBox, length: f64, depth: Option<f64>) -> bool {
    if !(length.is_finite() && length > 0.0) {
        return false;
    }
    let (short, long) = (
        fitted.size.x.min(fitted.size.y),
        fitted.size.x.max(fitted.size.y),
    );
    let across_depth = depth.filter(|d| *d > 0.0 && *d < length).is_some_and(|d| {
        let (to_depth, to_length) = ((long / d).ln().abs(), (long / length).ln().abs());
        to_depth < to_length && to_depth <= DEPTH_MARGIN.ln()
    });
    long < SEEN_IN_PART_SHARE * length || (across_depth && short < SEEN_IN_PART_SHARE * length)
}

/// How a box grows along one horizontal axis: by `ahead` along the axis' direction and `behind`
/// against it.
#[derive(Debug, Clone, Copy)]
struct Growth {
    along_x: bool,
    ahead: f64,
    behind: f64,
    /// The share of the missing length the growth makes up.
    share: f64,
}

impl Growth {
    fn total(&self) -> f64 {
        self.ahead + self.behind
    }

    /// `fitted` grown so (unchanged under [`MIN_GROWTH_M`]).
    fn applied_to(&self, fitted: OrientedBox) -> OrientedBox {
        if self.total() < MIN_GROWTH_M {
            return fitted;
        }
        let axis = length_axis(&fitted, self.along_x);
        let mut grown = fitted;
        let centre = fitted.centre.truncate() + axis * ((self.ahead - self.behind) / 2.0);
        grown.centre = DVec3::new(centre.x, centre.y, fitted.centre.z);
        if self.along_x {
            grown.size.x += self.total();
        } else {
            grown.size.y += self.total();
        }
        grown
    }
}

/// The unit ground-plane axis along `fitted`'s x side (`along_x`) or its y side.
fn length_axis(fitted: &OrientedBox, along_x: bool) -> DVec2 {
    let (c, s) = (fitted.yaw.cos(), fitted.yaw.sin());
    if along_x {
        DVec2::new(c, s)
    } else {
        DVec2::new(-s, c)
    }
}

/// How `fitted` grows to `length` along its x side (`along_x`) or its y side: each end up to
/// the room [`free_room`] leaves it, half the missing length each where both have room.
fn growth_along(fitted: &OrientedBox, blocked: &[Vec3], along_x: bool, length: f64) -> Growth {
    let axis = length_axis(fitted, along_x);
    let (side, across) = if along_x {
        (fitted.size.x, fitted.size.y)
    } else {
        (fitted.size.y, fitted.size.x)
    };
    let missing = length - side;
    let room = |sign: f64| free_room(fitted, blocked, axis * sign, side, across, missing);
    let (ahead, behind) = (room(1.0), room(-1.0));
    let half = missing / 2.0;
    let (ahead, behind) = if ahead >= half && behind >= half {
        (half, half)
    } else if ahead < behind {
        (ahead, behind.min(missing - ahead))
    } else {
        (ahead.min(missing - behind), behind)
    };
    Growth {
        along_x,
        ahead,
        behind,
        share: (ahead + behind) / missing.max(f64::EPSILON),
    }
}

/// How far (m, up to `missing`) `fitted` may grow beyond its end in direction `towards` (unit,
/// along its `side`-long axis, `across` wide) before it comes within [`STOP_SHORT_M`] of a
/// `blocked` point.
fn free_room(
    fitted: &OrientedBox,
    blocked: &[Vec3],
    towards: DVec2,
    side: f64,
    across: f64,
    missing: f64,
) -> f64 {
    let normal = DVec2::new(-towards.y, towards.x);
    blocked
        .iter()
        .map(|p| p.as_dvec3() - fitted.centre)
        .filter(|d| {
            d.is_finite()
                && d.truncate().dot(normal).abs() <= across / 2.0
                && d.z.abs() <= fitted.size.z / 2.0
        })
        .map(|d| d.truncate().dot(towards) - side / 2.0)
        .filter(|&beyond| beyond > 0.0)
        .fold(missing, |room, beyond| {
            room.min((beyond - STOP_SHORT_M).max(0.0))
        })
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
    fn a_table_fitted_above_its_cut_off_feet_reaches_down_to_the_floor() {
        // Its top at 0.82 m; the window cut the floor slab and the legs' lowest 0.12 m away.
        let fitted = OrientedBox {
            centre: DVec3::new(2.0, 1.0, 0.47),
            size: DVec3::new(1.1, 0.7, 0.7),
            yaw: 0.0,
        };
        let standing = down_to_floor(fitted, 0.0);
        assert!((standing.size.z - 0.82).abs() < 1e-9, "{standing:?}");
        assert!((standing.centre.z - 0.41).abs() < 1e-9);
        // Within the floor's own 2 cm resolution it already stands.
        let resting = OrientedBox {
            centre: DVec3::new(2.0, 1.0, 0.365),
            ..fitted
        };
        assert_eq!(down_to_floor(resting, 0.0), resting);
    }

    #[test]
    fn a_lamp_seen_as_its_shade_grows_down_to_the_table_under_it() {
        // The shade, 0.93-1.21 m up; the lamp is 0.48 m tall and its table's top 0.75 m up.
        let shade = OrientedBox {
            centre: DVec3::new(1.0, 2.0, 1.07),
            size: DVec3::new(0.28, 0.28, 0.28),
            yaw: 0.4,
        };
        let lamp = grown_down_to_rest(shade, 0.48, || 0.75);
        assert!((lamp.size.z - 0.46).abs() < 1e-9, "{lamp:?}");
        assert!((lamp.centre.z - 0.98).abs() < 1e-9);
        assert_eq!(lamp.centre.truncate(), shade.centre.truncate());
        // Nothing seen under it: down to its typical height.
        let free = grown_down_to_rest(shade, 0.48, || f64::NEG_INFINITY);
        assert!((free.size.z - 0.48).abs() < 1e-9, "{free:?}");
        // Seen nearly whole (a pillow as flat as pillows are), or non-finite: as it is.
        assert_eq!(grown_down_to_rest(shade, 0.3, || 0.0), shade);
        assert_eq!(grown_down_to_rest(shade, f64::NAN, || 0.0), shade);
        let nan = OrientedBox {
            size: DVec3::NAN,
            ..shade
        };
        assert!(grown_down_to_rest(nan, 0.48, || 0.0).size.x.is_nan());
    }

    #[test]
    fn standing_tall_and_degenerate_boxes_keep_their_box() {
        let on_floor = OrientedBox {
            centre: DVec3::new(1.0, 2.0, 0.51),
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

    /// A desk seen in part: 0.5 m of its length along x (yaw `yaw`), its whole 0.69 m depth.
    fn desk_piece(yaw: f64) -> OrientedBox {
        OrientedBox {
            centre: DVec3::new(2.0, 1.0, 0.375),
            size: DVec3::new(0.5, 0.69, 0.75),
            yaw,
        }
    }

    /// A point `beyond` m past the desk piece's end in direction `sign` along its length.
    fn past_end(piece: &OrientedBox, sign: f64, beyond: f64) -> Vec3 {
        let axis = DVec2::new(piece.yaw.cos(), piece.yaw.sin()) * sign;
        let p = piece.centre.truncate() + axis * (piece.size.x / 2.0 + beyond);
        DVec3::new(p.x, p.y, 0.7).as_vec3()
    }

    #[test]
    fn an_object_seen_in_part_grows_along_its_length_away_from_where_a_view_saw_past_it() {
        for yaw in [0.0, 0.8, -2.5] {
            let piece = desk_piece(yaw);
            let axis = DVec2::new(yaw.cos(), yaw.sin());
            let end = |b: &OrientedBox, sign: f64| {
                (b.centre - piece.centre).truncate().dot(axis) + sign * b.size.x / 2.0
            };
            // A view saw the floor 0.3 m past the +x end: the desk ends there.
            let free = [past_end(&piece, 1.0, 0.3)];
            let grown = grown_to_length(piece, &free, 1.38, Some(0.69));
            assert!((grown.size.x - 1.38).abs() < 1e-9, "{grown:?}");
            assert_eq!((grown.size.y, grown.size.z), (0.69, 0.75));
            assert!(end(&grown, 1.0) <= end(&piece, 1.0) + 0.3 - STOP_SHORT_M + 1e-6);
            assert!(end(&grown, -1.0) < end(&piece, -1.0) - 0.5, "{grown:?}");
            // Nobody saw past either end: half the missing length on each.
            let unseen = grown_to_length(piece, &[], 1.38, Some(0.69));
            assert!((unseen.size.x - 1.38).abs() < 1e-9);
            assert!((unseen.centre - piece.centre).length() < 1e-9);
            // Every end seen right where it is: the piece is the whole object.
            let across = DVec2::new(-yaw.sin(), yaw.cos());
            let beside = |sign: f64| {
                let p = piece.centre.truncate() + across * sign * (piece.size.y / 2.0 + 0.1);
                DVec3::new(p.x, p.y, 0.7).as_vec3()
            };
            let closed = [
                past_end(&piece, 1.0, 0.1),
                past_end(&piece, -1.0, 0.1),
                beside(1.0),
                beside(-1.0),
            ];
            assert_eq!(grown_to_length(piece, &closed, 1.38, Some(0.69)), piece);
        }
    }

    #[test]
    fn free_space_beside_or_above_the_object_does_not_stop_it_and_near_whole_boxes_stay() {
        let piece = desk_piece(0.0);
        // Free space 1 m to the side of the +x end, and 1 m above it: not past the end.
        let beside = past_end(&piece, 1.0, 0.3) + Vec3::new(0.0, 1.0, 0.0);
        let above = past_end(&piece, 1.0, 0.3) + Vec3::new(0.0, 0.0, 1.0);
        let grown = grown_to_length(piece, &[beside, above], 1.38, Some(0.69));
        assert!((grown.centre - piece.centre).length() < 1e-9, "{grown:?}");
        // A box whose longer side is at least SEEN_IN_PART_SHARE of the typical length, and
        // nearer the length than the depth, is no piece, however short its other side.
        let mut whole = piece;
        whole.size.x = 1.0;
        whole.size.y = 0.3;
        assert_eq!(grown_to_length(whole, &[], 1.38, Some(0.69)), whole);
    }

    #[test]
    fn a_piece_seen_across_its_width_grows_along_the_side_that_is_not_its_depth() {
        // 0.3 m along x, 0.69 along y (the desk's depth): the length is x.
        let mut piece = desk_piece(0.0);
        piece.size.x = 0.3;
        let grown = grown_to_length(piece, &[], 1.38, Some(0.69));
        assert!(
            (grown.size.x - 1.38).abs() < 1e-9 && grown.size.y == 0.69,
            "{grown:?}"
        );
        // Without a depth prior, the longer side is the length.
        let grown = grown_to_length(piece, &[], 1.38, None);
        assert!(
            (grown.size.y - 1.38).abs() < 1e-9 && grown.size.x == 0.3,
            "{grown:?}"
        );
    }

    #[test]
    fn an_object_seen_across_its_whole_depth_grows_along_its_length_but_a_whole_one_does_not() {
        // A bed's foot end (the default vocabulary's bed: 1.97 m long, 1.55 m deep): 1.64 m
        // across and 0.76 m of its length, the camera beyond its foot (free space at y = 0.6).
        let foot = OrientedBox {
            centre: DVec3::new(0.0, 0.0, 0.25),
            size: DVec3::new(1.64, 0.76, 0.5),
            yaw: 0.0,
        };
        let beyond_the_foot = [Vec3::new(0.0, 0.6, 0.25)];
        let grown = grown_to_length(foot, &beyond_the_foot, 1.97, Some(1.55));
        let (lo, hi) = (
            grown.centre.y - grown.size.y / 2.0,
            grown.centre.y + grown.size.y / 2.0,
        );
        assert!(
            (grown.size.y - 1.97).abs() < 1e-9 && grown.size.x == 1.64 && hi <= 0.51,
            "{grown:?} {lo} {hi}"
        );
        // A cabinet smaller than the typical one (0.8 m long, 0.5 m deep), seen whole: its
        // longer side is nearer the length than the depth, so nothing is missing.
        let cabinet = OrientedBox {
            centre: DVec3::new(0.0, 0.0, 0.9),
            size: DVec3::new(0.72, 0.45, 1.8),
            yaw: 0.0,
        };
        assert!(!is_seen_in_part(&cabinet, 0.8, Some(0.5)));
        assert_eq!(grown_to_length(cabinet, &[], 0.8, Some(0.5)), cabinet);
        // Without a depth prior, only the old rule: both sides short of the length.
        assert!(!is_seen_in_part(&foot, 1.97, None) && is_seen_in_part(&foot, 1.97, Some(1.55)));
    }

    #[test]
    fn degenerate_boxes_lengths_and_free_points_leave_boxes_finite() {
        let piece = desk_piece(0.3);
        let nan = [Vec3::NAN, Vec3::new(f32::INFINITY, 0.0, 0.0)];
        let grown = grown_to_length(piece, &nan, 1.38, Some(0.69));
        assert!(
            grown.centre.is_finite() && grown.size.is_finite(),
            "{grown:?}"
        );
        for length in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert_eq!(grown_to_length(piece, &[], length, Some(0.69)), piece);
        }
        let mut flat = piece;
        flat.size = DVec3::ZERO;
        let grown = grown_to_length(flat, &[], 1.38, Some(0.0));
        assert!(
            grown.centre.is_finite() && grown.size.is_finite(),
            "{grown:?}"
        );
        let mut lost = piece;
        lost.centre = DVec3::NAN;
        let kept = grown_to_length(lost, &[], 1.38, None);
        assert!(kept.centre.is_nan() && kept.size == lost.size);
    }

    #[test]
    fn a_box_as_deep_as_no_object_of_its_name_is_no_piece_of_one() {
        // A trash bin named sofa (typical length 1.91 m, depth 0.86 m): 0.4 m across whichever
        // side is its length, far shallower than a sofa.
        let bin = OrientedBox {
            centre: DVec3::new(1.0, 1.0, 0.3),
            size: DVec3::new(0.4, 0.4, 0.6),
            yaw: 0.3,
        };
        assert_eq!(grown_to_length(bin, &[], 1.91, Some(0.86)), bin);
        // A monitor's screen seen from the front (0.29 wide, 0.09 thick; length 0.55 m, depth
        // 0.16 m): its width is no depth, and its thickness is too thin to be one.
        let screen = OrientedBox {
            centre: DVec3::new(1.0, 1.0, 1.0),
            size: DVec3::new(0.29, 0.09, 0.3),
            yaw: 0.0,
        };
        assert_eq!(grown_to_length(screen, &[], 0.55, Some(0.16)), screen);
        // Without a depth prior nothing says so: the longer side grows.
        let grown = grown_to_length(bin, &[], 1.91, None);
        assert!((grown.size.x - 1.91).abs() < 1e-9, "{grown:?}");
    }
}
