//! The map's object list, as the node publishes it, the evaluation scores it and queries pick
//! from it (ARCHITECTURE.md §4, step 7): which instances are listed (not structure, not small
//! unsure pieces, not longer than any object of the vocabulary), the name each is listed under,
//! and the box it publishes: fitted to its points, a face seen from one side completed back to the
//! wall behind it ([`Walls::place`]) or to its name's typical depth ([`amodal`]), and furniture
//! that stands on the floor reaching down to it.

use glam::Vec3;

use super::instance::Fitted;
use super::walls::{is_low, is_thin, Walls};
use super::{amodal, Instance, SceneMap};
use crate::group::semantics::{
    ClassPriors, MeasuredSize, Standing, Vocabulary, MIN_LISTED_GAUSSIANS,
};
use crate::recon::boxes::OrientedBox;

/// The box an instance publishes: `fitted`, completed when it is a surface seen from one side
/// ([`Walls::place`]; `walls` is built from `map` at the first thin box), or `None` when it is
/// a patch of the room itself (floor, or a wall's plane) and no object.
pub fn published_box(
    fitted: OrientedBox,
    walls: &std::cell::OnceCell<Walls>,
    map: &SceneMap,
    vocabulary: Option<&Vocabulary>,
) -> Option<OrientedBox> {
    if !is_thin(&fitted) && !is_low(&fitted) {
        return Some(fitted);
    }
    map_walls(walls, map, vocabulary).place(fitted)
}

/// The map's structure as [`Walls`], built at the first call.
fn map_walls<'a>(
    walls: &'a std::cell::OnceCell<Walls>,
    map: &SceneMap,
    vocabulary: Option<&Vocabulary>,
) -> &'a Walls {
    walls.get_or_init(|| {
        Walls::of_map(map, |i| {
            vocabulary.is_some_and(|v| v.is_structure(&i.prototype))
        })
    })
}

/// The map's object list, as the node publishes it, the evaluation scores it and queries pick
/// from it: instances the vocabulary lists (structure and small unsure pieces left out:
/// [`Vocabulary::is_listed`]), each with its published box ([`published_box`] of the box `fit`
/// gives it) and its names, less those whose box is a patch of the room itself.
pub fn object_list<'a>(
    map: &'a SceneMap,
    vocabulary: Option<&Vocabulary>,
    fit: impl FnMut(&Instance, bool) -> Fitted,
) -> Vec<Listed<'a>> {
    list(map, vocabulary, fit, false)
}

/// [`object_list`] with the tentative candidates queries may also answer
/// ([`Vocabulary::is_tentative`]: small pieces the list holds back, seen by one window or named
/// unsurely, whose best name scores at least [`crate::group::semantics::TENTATIVE_NAME`], and no
/// small piece of what their name names: [`is_small_piece`]), marked [`Listed::tentative`].
pub fn object_list_with_tentative<'a>(
    map: &'a SceneMap,
    vocabulary: Option<&Vocabulary>,
    fit: impl FnMut(&Instance, bool) -> Fitted,
) -> Vec<Listed<'a>> {
    list(map, vocabulary, fit, true)
}

/// [`object_list`], with the tentative candidates where `with_tentative` asks for them.
fn list<'a>(
    map: &'a SceneMap,
    vocabulary: Option<&Vocabulary>,
    mut fit: impl FnMut(&Instance, bool) -> Fitted,
    with_tentative: bool,
) -> Vec<Listed<'a>> {
    let walls = std::cell::OnceCell::new();
    // Every instance's bounds, once per list and only if a box may grow ([`seen_in_part`]).
    let bounds = std::cell::OnceCell::new();
    // Without a vocabulary nothing is named, so no prior applies.
    let no_priors = ClassPriors::default();
    let priors = vocabulary.map_or(&no_priors, |v| &v.priors);
    // Whether the semantic features named anything in this map: then an instance they left
    // unnamed is one no feature pixel saw.
    let features_name = vocabulary.is_some() && map.instances.iter().any(|i| i.is_named());
    map.instances
        .iter()
        .filter_map(|i| {
            let standing = vocabulary.map_or(Standing::Listed, |v| {
                v.standing(&i.prototype, i.gaussians.len(), i.observations)
            });
            let listed = standing == Standing::Listed;
            let tentative = with_tentative && standing == Standing::Tentative;
            if !listed && !tentative {
                tracing::debug!(
                    instance = %i.id,
                    gaussians = i.gaussians.len(),
                    sightings = i.observations,
                    best = ?vocabulary.and_then(|v| v.hypotheses(&i.prototype, 1).pop()),
                    "not listed: structure, or a small piece seen once or named unsurely"
                );
            }
            (listed || tentative).then_some((i, tentative))
        })
        .filter_map(|(i, tentative)| {
            // Longer than any object of the vocabulary could be: no object (a room-sized
            // instance named "sink" was listed on benchmark 9604).
            let size = i.measured_size();
            if vocabulary.is_some_and(|v| v.admits_no_object(size.length_m)) {
                tracing::debug!(instance = %i.id, length = size.length_m, "not listed: longer than any object");
                return None;
            }
            // Named once: three completions, the published hypotheses and referring read these
            // names.
            let names = vocabulary
                .map(|v| i.name_probabilities(v, size))
                .unwrap_or_default();
            let name = vocabulary
                .and_then(|v| v.ranked(&names, 1).into_iter().next())
                .map(|(name, _)| name);
            let name = name.as_deref();
            if is_small_piece(i, name, size, priors, features_name) {
                tracing::debug!(instance = %i.id, length = size.length_m, "not listed: a small piece");
                return None;
            }
            let box_like = name.is_some_and(|n| priors.typical_depth(n).is_some());
            let fitted = fit(i, box_like);
            let publish = |b: OrientedBox| {
                published_box(b, &walls, map, vocabulary).map(|placed| {
                    let named = name.map(|n| (n, priors));
                    seen_from_one_side(placed, i, named, || map_walls(&walls, map, vocabulary))
                })
            };
            // A face seen through range noise is a slab as deep as the noise, which no
            // completion takes for a face; its surface is completed where a clean camera's
            // would be. Only for box-like furniture (names with a typical depth), and only that
            // completion is taken from the surface: planes fitted over a curved object (a bin,
            // a plant, a pillow) make it smaller than it is, or a slab completed to the wall.
            let completed_face = fitted.surface.and_then(|surface| {
                publish(surface).filter(|completed| deepened_face(&surface, completed))
            });
            completed_face.or_else(|| publish(fitted.points)).map(|b| {
                let b = seen_in_part(b, i, name.map(|n| (n, priors)), map, &bounds, || {
                    map_walls(&walls, map, vocabulary)
                });
                let stands = name.is_some_and(|n| priors.stands_on_floor(n));
                let b = match name.and_then(|n| priors.typical_height(n)) {
                    Some(height) => amodal::grown_down_to_rest(b, height, || {
                        let floor = map_walls(&walls, map, vocabulary).floor();
                        surface_under(&b, i, map, map_bounds(&bounds, map), floor)
                    }),
                    None => b,
                };
                Listed {
                    instance: i,
                    bbox: standing_on_floor(b, stands, &walls, map, vocabulary),
                    names,
                    tentative,
                }
            })
        })
        .collect()
}

/// Whether `instance` is a small piece of what its `name` names: fewer Gaussians than
/// [`MIN_LISTED_GAUSSIANS`] and a `size` no object of the name has ([`ClassPriors::admits_size`]:
/// a table's leg named table, a 9 cm sliver named chair), so neither listed, however often seen or
/// surely named, nor a tentative candidate for queries; a name without priors admits any size. Read on benchmark 15200-15219 and layouts
/// 920-939 (precision +1.4 and +0.5 points), fresh on 15400-15419 and layouts 940-959 (+1.6 and
/// +0.7): none of the 8 instances it left out was an object.
///
/// Unnamed, it is a piece where the `features_name` others: no feature pixel ever fell on it, so
/// it is thinner than one (a shelf's rim, a 6 cm line at 1.2 m on layouts 952). Every small
/// unnamed instance listed in 25 evaluations before this rule (11, on benchmark 15200 and layouts
/// 880 and 940) was no object.
fn is_small_piece(
    instance: &Instance,
    name: Option<&str>,
    size: MeasuredSize,
    priors: &ClassPriors,
    features_name: bool,
) -> bool {
    instance.gaussians.len() < MIN_LISTED_GAUSSIANS
        && match name {
            Some(name) => !priors.admits_size(name, size),
            None => features_name,
        }
}

/// One instance of the object list.
#[derive(Debug, Clone, PartialEq)]
pub struct Listed<'a> {
    pub instance: &'a Instance,
    /// Its published box.
    pub bbox: OrientedBox,
    /// p(name) for every phrase of the vocabulary, in its order ([`Instance::name_probabilities`];
    /// empty without a vocabulary).
    pub names: Vec<f32>,
    /// A tentative candidate for queries, not in the published list
    /// ([`object_list_with_tentative`]).
    pub tentative: bool,
}

/// Whether `completed` is the vertical face `surface` completed behind it (back to a wall or
/// to its name's depth): its thinner horizontal side grown, its height as it was.
fn deepened_face(surface: &OrientedBox, completed: &OrientedBox) -> bool {
    let thin = |b: &OrientedBox| b.size.x.min(b.size.y);
    thin(completed) > thin(surface) + 0.01 && (completed.size.z - surface.size.z).abs() < 1e-6
}

/// `placed` completed away from the instance's viewpoint to its name's typical depth when it is
/// an object's face seen from one side ([`amodal`]); as it is without a name, a depth or a
/// viewpoint. Objects do not go through walls: with a wall closer behind the face than the
/// typical depth, the object fills the space back to it, and with one closer than any object of
/// the name is deep ([`ClassPriors::smallest_depth`]), the face is the object's back (a chair's
/// backrest seen over a table, from its seat's side) and the object stands in front of it.
pub(super) fn seen_from_one_side<'w>(
    placed: OrientedBox,
    instance: &Instance,
    named: Option<(&str, &ClassPriors)>,
    walls: impl FnOnce() -> &'w Walls,
) -> OrientedBox {
    let (Some((name, priors)), Some(viewpoint)) = (named, instance.viewpoint) else {
        return placed;
    };
    let Some(depth) = priors.typical_depth(name) else {
        return placed;
    };
    let completed = amodal::complete_away_from(placed, viewpoint, depth);
    let grown = (completed.centre - placed.centre).truncate();
    if completed == placed || grown.length() <= 0.0 {
        return completed;
    }
    let Some(gap) = walls().wall_towards(&placed, grown.normalize()) else {
        return completed;
    };
    let thin = placed.size.x.min(placed.size.y);
    if gap + thin / 2.0 >= depth {
        completed
    } else if priors
        .smallest_depth(name)
        .is_some_and(|smallest| gap + thin / 2.0 < smallest)
    {
        amodal::complete_toward(placed, viewpoint, depth)
    } else {
        amodal::complete_away_from(placed, viewpoint, gap + thin / 2.0)
    }
}

/// `placed` grown along its length to its name's typical length where it is an object seen in
/// part, as far as no view saw past the end it grows from, no other instance of `map` stands
/// there and no wall rises over it ([`Walls::over`]: a desk against a wall, seen as a square of
/// its top, grew through the wall; benchmark 12602 and 12608) ([`amodal::grown_to_length`]); as
/// it is without a name or a typical length.
fn seen_in_part<'w>(
    placed: OrientedBox,
    instance: &Instance,
    named: Option<(&str, &ClassPriors)>,
    map: &SceneMap,
    bounds: &std::cell::OnceCell<Vec<(Vec3, Vec3)>>,
    walls: impl FnOnce() -> &'w Walls,
) -> OrientedBox {
    let Some((name, priors)) = named else {
        return placed;
    };
    let Some(length) = priors.typical_length(name) else {
        return placed;
    };
    // Blockers are gathered only for a box that may grow.
    if !amodal::is_seen_in_part(&placed, length, priors.typical_depth(name)) {
        return placed;
    }
    // As far as the box could grow along either horizontal axis.
    let reach = (length + placed.size.x.max(placed.size.y)) as f32;
    let mut blocked = instance.seen_free.clone();
    blocked.extend(others_within(
        &placed,
        instance,
        map,
        map_bounds(bounds, map),
        reach,
    ));
    blocked.extend(walls().over(&placed, reach));
    amodal::grown_to_length(placed, &blocked, length, priors.typical_depth(name))
}

/// Points of `map`'s other instances (objects and structure, a sample of each; `bounds` in the
/// map's order) within `reach` of `placed`'s centre along either horizontal axis (the space it
/// could grow into): from a hand above the floor (the floor under it blocks nothing) to its top.
fn others_within<'m>(
    placed: &OrientedBox,
    instance: &Instance,
    map: &'m SceneMap,
    bounds: &'m [(Vec3, Vec3)],
    reach: f32,
) -> impl Iterator<Item = Vec3> + 'm {
    let centre = placed.centre.as_vec3();
    let (bottom, top) = (
        (placed.centre.z - placed.size.z / 2.0) as f32 + ABOVE_FLOOR_M,
        (placed.centre.z + placed.size.z / 2.0) as f32,
    );
    let near = move |p: &Vec3| {
        (p.x - centre.x).abs() <= reach
            && (p.y - centre.y).abs() <= reach
            && p.z > bottom
            && p.z < top
    };
    let id = instance.id.clone();
    map.instances
        .iter()
        .zip(bounds)
        .filter(move |(other, _)| other.id != id)
        .filter(move |(_, b)| within_reach(b, centre, reach) && b.0.z < top && b.1.z > bottom)
        .flat_map(move |(other, _)| {
            let step = other.gaussians.len().div_ceil(OTHER_SAMPLES).max(1);
            other
                .gaussians
                .means
                .iter()
                .step_by(step)
                .copied()
                .filter(near)
        })
}

/// Every instance's bounds, in `map`'s order: computed once per list, at the first box that
/// needs them.
fn map_bounds<'c>(
    bounds: &'c std::cell::OnceCell<Vec<(Vec3, Vec3)>>,
    map: &SceneMap,
) -> &'c [(Vec3, Vec3)] {
    bounds.get_or_init(|| map.instances.iter().map(Instance::bounds).collect())
}

/// Whether bounds (`lo`, `hi`) come within `reach` of `centre` horizontally (per axis).
fn within_reach((lo, hi): &(Vec3, Vec3), centre: Vec3, reach: f32) -> bool {
    lo.x - centre.x <= reach
        && centre.x - hi.x <= reach
        && lo.y - centre.y <= reach
        && centre.y - hi.y <= reach
}

/// Points of another instance above this (m) over the grown box's bottom block it: the floor it
/// stands on does not.
const ABOVE_FLOOR_M: f32 = 0.1;
/// Points sampled from each other instance: enough to find a neighbour or a wall.
const OTHER_SAMPLES: usize = 1024;

/// The height of the highest surface under `placed` (m): the highest point of `map`'s other
/// instances below its bottom within its footprint grown by [`SUPPORT_MARGIN_M`], or the
/// `floor`; `-inf` when neither is known. Read only for boxes that may grow
/// ([`amodal::grown_down_to_rest`]); `bounds` (each instance's, in the map's order) skip the
/// instances nowhere under it.
fn surface_under(
    placed: &OrientedBox,
    instance: &Instance,
    map: &SceneMap,
    bounds: &[(Vec3, Vec3)],
    floor: Option<f32>,
) -> f64 {
    let bottom = placed.centre.z - placed.size.z / 2.0;
    let floor = floor.map_or(f64::NEG_INFINITY, f64::from);
    if !bottom.is_finite() {
        return floor;
    }
    let (cos, sin) = (placed.yaw.cos(), placed.yaw.sin());
    let (half_x, half_y) = (
        placed.size.x / 2.0 + SUPPORT_MARGIN_M,
        placed.size.y / 2.0 + SUPPORT_MARGIN_M,
    );
    let under = |p: &&Vec3| {
        let d = p.as_dvec3() - placed.centre;
        let (along, across) = (d.x * cos + d.y * sin, d.y * cos - d.x * sin);
        along.abs() <= half_x && across.abs() <= half_y && f64::from(p.z) < bottom - BELOW_M
    };
    // The grown footprint's reach from its centre, whatever its yaw.
    let reach = half_x.hypot(half_y) as f32;
    let centre = placed.centre.as_vec3();
    let below = (bottom - BELOW_M) as f32;
    map.instances
        .iter()
        .zip(bounds)
        .filter(|(other, b)| {
            other.id != instance.id && within_reach(b, centre, reach) && b.0.z < below
        })
        .flat_map(|(other, _)| other.gaussians.means.iter().filter(under))
        .map(|p| f64::from(p.z))
        .fold(floor, f64::max)
}

/// What lies right under an object is hidden by it (a pillow's bed, a box's shelf board), so the
/// surface it rests on is read this far (m) around its footprint. Under the footprint alone the
/// next surface seen was often the floor: extending boxes to the surface under them (before the
/// typical height bounded it) cost benchmark 7000-7019 recall@0.25 -3.8 points, -1.6 with this
/// margin, pillows and boxes grown to the floor. Read on benchmark 12000-12019 and 7000-7019;
/// checked with [`amodal::RESTING_HEIGHT_SHARE`] on the ranges that names.
const SUPPORT_MARGIN_M: f64 = 0.25;
/// A point at least this far (m) under a box's bottom is under it, not its own bottom's noise (a
/// choice: the floor estimate's 2 cm bands).
const BELOW_M: f64 = 0.02;

/// `placed` extended down to the map's floor when the instance's best name `stands` there (its
/// class prior) and the box floats ([`amodal::down_to_floor`]); as it is otherwise.
fn standing_on_floor(
    placed: OrientedBox,
    stands: bool,
    walls: &std::cell::OnceCell<Walls>,
    map: &SceneMap,
    vocabulary: Option<&Vocabulary>,
) -> OrientedBox {
    if !stands {
        return placed;
    }
    match map_walls(walls, map, vocabulary).floor() {
        Some(floor) => amodal::down_to_floor(placed, f64::from(floor)),
        None => placed,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An instance named by `prototype` over the points of an axis-aligned cuboid's surface.
    fn cuboid<const N: usize>(id: &str, lo: Vec3, hi: Vec3, prototype: [f32; N]) -> Instance {
        let steps = |a: f32, b: f32| ((b - a) / 0.04).ceil().max(1.0) as usize;
        let n = [steps(lo.x, hi.x), steps(lo.y, hi.y), steps(lo.z, hi.z)];
        let mut points = Vec::new();
        for i in 0..=n[0] {
            for j in 0..=n[1] {
                for k in 0..=n[2] {
                    if [
                        i == 0 || i == n[0],
                        j == 0 || j == n[1],
                        k == 0 || k == n[2],
                    ]
                    .contains(&true)
                    {
                        let t = Vec3::new(i as f32, j as f32, k as f32)
                            / Vec3::new(n[0] as f32, n[1] as f32, n[2] as f32);
                        points.push(lo + (hi - lo) * t);
                    }
                }
            }
        }
        Instance::of_points(id, &points, &prototype)
    }

    const DESK: [f32; 2] = [1.0, 0.0];

    /// The default vocabulary's desk (typical length 1.38 m, depth 0.69 m), and `other`.
    fn desks() -> Vocabulary {
        Vocabulary {
            phrases: vec!["desk".into(), "other".into()],
            embeddings: vec![vec![1.0, 0.0], vec![0.0, 1.0]],
            temperature: 0.05,
            priors: ClassPriors::builtin(),
        }
    }

    /// The published box of instance `id` in `map`'s object list.
    fn listed_box(map: &SceneMap, id: &str) -> OrientedBox {
        let vocabulary = desks();
        let list = object_list(map, Some(&vocabulary), |i, _| i.oriented_box().into());
        list.iter()
            .find(|l| l.instance.id == id)
            .expect("listed")
            .bbox
    }

    /// The x extent of `b`, whatever its yaw's quarter turn.
    fn x_extent(b: &OrientedBox) -> (f64, f64) {
        let half = if b.yaw.cos().abs() > 0.5 {
            b.size.x
        } else {
            b.size.y
        } / 2.0;
        (b.centre.x - half, b.centre.x + half)
    }

    /// The y extent of `b`, whatever its yaw's quarter turn.
    fn y_extent(b: &OrientedBox) -> (f64, f64) {
        let turned = OrientedBox {
            centre: glam::DVec3::new(b.centre.y, b.centre.x, b.centre.z),
            yaw: b.yaw + std::f64::consts::FRAC_PI_2,
            ..*b
        };
        x_extent(&turned)
    }

    #[test]
    fn a_small_piece_no_object_of_its_name_is_as_narrow_is_not_listed() {
        // Surely named desk, seen by three windows, under MIN_LISTED_GAUSSIANS each: a 9 cm leg
        // (desks are never under 0.6 m across) and a 44 cm stretch of a desk's edge.
        let leg = cuboid("leg", Vec3::ZERO, Vec3::new(0.08, 0.08, 0.2), DESK);
        let edge = cuboid("edge", Vec3::X, Vec3::new(1.44, 0.04, 0.04), DESK);
        // A leg as narrow, but as large as an object: listed (the rule is for pieces).
        let post = cuboid("post", Vec3::Y, Vec3::new(0.08, 1.08, 0.5), DESK);
        for small in [&leg, &edge] {
            assert!(small.gaussians.len() < MIN_LISTED_GAUSSIANS, "{}", small.id);
        }
        assert!(post.gaussians.len() >= MIN_LISTED_GAUSSIANS);
        let map = SceneMap {
            instances: vec![leg, edge, post],
            ..SceneMap::default()
        };
        let vocabulary = desks();
        let list = object_list(&map, Some(&vocabulary), |i, _| i.oriented_box().into());
        let ids: Vec<&str> = list.iter().map(|l| l.instance.id.as_str()).collect();
        assert_eq!(ids, ["edge", "post"]);
    }

    #[test]
    fn a_small_instance_no_feature_pixel_saw_is_not_listed_where_the_features_name_others() {
        // A shelf's rim: a 3 cm line no feature pixel fell on (empty prototype), beside a named
        // desk; an unnamed instance as large as an object stays listed.
        let rim = cuboid("rim", Vec3::Z, Vec3::new(0.3, 0.03, 1.0), [0.0; 0]);
        let desk = cuboid("desk", Vec3::Y, Vec3::new(1.4, 1.7, 0.75), DESK);
        let slab = cuboid("slab", Vec3::X * 3.0, Vec3::new(4.0, 1.0, 0.4), [0.0; 0]);
        assert!(rim.gaussians.len() < MIN_LISTED_GAUSSIANS);
        assert!(slab.gaussians.len() >= MIN_LISTED_GAUSSIANS);
        let vocabulary = desks();
        let ids = |map: &SceneMap| -> Vec<String> {
            object_list(map, Some(&vocabulary), |i, _| i.oriented_box().into())
                .iter()
                .map(|l| l.instance.id.clone())
                .collect()
        };
        let map = SceneMap {
            instances: vec![rim.clone(), desk, slab.clone()],
            ..SceneMap::default()
        };
        assert_eq!(ids(&map), ["desk", "slab"]);
        // Without semantic features nothing is named, so the rim is no less an object than any.
        let unnamed = SceneMap {
            instances: vec![rim, slab],
            ..SceneMap::default()
        };
        assert_eq!(ids(&unnamed), ["rim", "slab"]);
    }

    #[test]
    fn a_desk_seen_in_part_grows_to_its_length_but_not_into_the_desk_beside_it_nor_past_free_space()
    {
        // Half a metre of a desk (x 0 to 0.5, its whole 0.69 m depth), seen in part.
        let piece = || {
            cuboid(
                "piece",
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(0.5, 0.69, 0.75),
                DESK,
            )
        };
        let floor = cuboid(
            "floor",
            Vec3::new(-3.0, -3.0, -0.02),
            Vec3::new(4.0, 4.0, 0.0),
            [0.0, 1.0],
        );
        let alone = SceneMap {
            instances: vec![piece(), floor.clone()],
            ..SceneMap::default()
        };
        let (lo, hi) = x_extent(&listed_box(&alone, "piece"));
        assert!(
            (hi - lo - 1.38).abs() < 0.02 && (lo + hi - 0.5).abs() < 0.02,
            "{lo} {hi}"
        );
        // Another desk touching its +x end (a row): it grows only the other way.
        let neighbour = cuboid(
            "next",
            Vec3::new(0.52, 0.0, 0.0),
            Vec3::new(1.9, 0.69, 0.75),
            DESK,
        );
        let row = SceneMap {
            instances: vec![piece(), neighbour, floor.clone()],
            ..SceneMap::default()
        };
        let (lo, hi) = x_extent(&listed_box(&row, "piece"));
        assert!(hi < 0.53 && (hi - lo - 1.38).abs() < 0.02, "{lo} {hi}");
        // And views saw the floor 0.4 m past its -x end and in front of it (a wall behind it):
        // it grows only to there.
        let mut seen = piece();
        seen.seen_free = vec![Vec3::new(-0.4, 0.35, 0.7), Vec3::new(0.25, -0.2, 0.7)];
        let wall = cuboid(
            "wall",
            Vec3::new(-3.0, 0.72, 0.0),
            Vec3::new(4.0, 0.74, 2.5),
            [0.0, 1.0],
        );
        let hemmed = SceneMap {
            instances: vec![seen, row.instances[1].clone(), floor, wall],
            ..SceneMap::default()
        };
        let (lo, hi) = x_extent(&listed_box(&hemmed, "piece"));
        assert!(hi < 0.53 && lo > -0.41 && lo < -0.2, "{lo} {hi}");
    }

    #[test]
    fn a_desk_seen_in_part_against_a_wall_does_not_grow_through_the_wall_hidden_behind_it() {
        // A 0.6 m square of a desk top's length (x 0 to 0.6, y 0 to 0.6), chairs at both of
        // its x ends, against a wall at y = -0.03 that the desk hides up to its top: the wall
        // shows above the desk and beside it, out of the desk's width.
        let structure = |id: &str, lo: Vec3, hi: Vec3| cuboid(id, lo, hi, [0.0, 1.0]);
        let map = SceneMap {
            instances: vec![
                cuboid(
                    "piece",
                    Vec3::new(0.0, 0.0, 0.0),
                    Vec3::new(0.6, 0.6, 0.75),
                    DESK,
                ),
                cuboid(
                    "left",
                    Vec3::new(-0.5, 0.0, 0.0),
                    Vec3::new(-0.05, 0.45, 0.9),
                    [0.0; 2],
                ),
                cuboid(
                    "right",
                    Vec3::new(0.65, 0.0, 0.0),
                    Vec3::new(1.1, 0.45, 0.9),
                    [0.0; 2],
                ),
                structure(
                    "floor",
                    Vec3::new(-3.0, -3.0, -0.02),
                    Vec3::new(4.0, 4.0, 0.0),
                ),
                structure(
                    "above",
                    Vec3::new(-0.6, -0.04, 0.77),
                    Vec3::new(1.2, -0.02, 2.5),
                ),
                structure(
                    "beside",
                    Vec3::new(-3.0, -0.04, 0.0),
                    Vec3::new(-1.2, -0.02, 2.5),
                ),
            ],
            ..SceneMap::default()
        };
        let (lo, hi) = y_extent(&listed_box(&map, "piece"));
        assert!(lo > -0.05 && hi - lo > 1.0, "{lo} {hi}");
    }

    #[test]
    fn a_lamp_seen_as_its_shade_reaches_down_to_its_table_and_a_pillow_keeps_its_box() {
        let (lamp, pillow, other) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]);
        let vocabulary = Vocabulary {
            phrases: vec!["lamp".into(), "pillow".into(), "other".into()],
            embeddings: vec![lamp.to_vec(), pillow.to_vec(), other.to_vec()],
            temperature: 0.05,
            priors: ClassPriors::builtin(),
        };
        let height = |name: &str| vocabulary.priors.typical_height(name).expect("a height");
        // A table top 0.75 m up (its legs unseen) and the floor, a lamp's shade 0.93-1.21 m up
        // over the table, a flat pillow at the table's far corner, and a shade over bare floor.
        let map = SceneMap {
            instances: vec![
                cuboid(
                    "table",
                    Vec3::new(0.0, 0.0, 0.7),
                    Vec3::new(1.2, 0.8, 0.75),
                    [0.0; 3],
                ),
                cuboid(
                    "floor",
                    Vec3::new(-3.0, -3.0, -0.02),
                    Vec3::new(4.0, 4.0, 0.0),
                    other,
                ),
                cuboid(
                    "shade",
                    Vec3::new(0.5, 0.3, 0.93),
                    Vec3::new(0.78, 0.58, 1.21),
                    lamp,
                ),
                cuboid(
                    "pillow",
                    Vec3::new(0.0, 0.0, 0.76),
                    Vec3::new(0.2, 0.3, 0.88),
                    pillow,
                ),
                cuboid(
                    "alone",
                    Vec3::new(2.5, 2.5, 1.0),
                    Vec3::new(2.78, 2.78, 1.28),
                    lamp,
                ),
            ],
            ..SceneMap::default()
        };
        let list = object_list(&map, Some(&vocabulary), |i, _| i.oriented_box().into());
        let z = |id: &str| {
            let b = list
                .iter()
                .find(|l| l.instance.id == id)
                .expect("listed")
                .bbox;
            (b.centre.z - b.size.z / 2.0, b.centre.z + b.size.z / 2.0)
        };
        let (bottom, top) = z("shade");
        assert!(
            (bottom - 0.75).abs() < 0.02 && (top - 1.21).abs() < 0.02,
            "{bottom} {top}"
        );
        let (bottom, top) = z("pillow");
        assert!(
            (bottom - 0.76).abs() < 0.02 && (top - 0.88).abs() < 0.02,
            "{bottom} {top}"
        );
        let (bottom, top) = z("alone");
        assert!(
            (top - bottom - height("lamp")).abs() < 0.02,
            "{bottom} {top}"
        );
    }
}
