//! The map's object list, as the node publishes it, the evaluation scores it and queries pick
//! from it (ARCHITECTURE.md §4, step 7): which instances are listed (not structure, not small
//! unsure pieces, not longer than any object of the vocabulary), the name each is listed under,
//! and the box it publishes: fitted to its points, a face seen from one side completed back to the
//! wall behind it ([`Walls::place`]) or to its name's typical depth ([`amodal`]), and furniture
//! that stands on the floor reaching down to it.

use super::instance::Fitted;
use super::walls::{is_low, is_thin, Walls};
use super::{amodal, Instance, SceneMap};
use crate::group::semantics::{ClassPriors, Standing, Vocabulary};
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
/// unsurely, whose best name scores at least [`crate::group::semantics::TENTATIVE_NAME`]),
/// marked [`Listed::tentative`].
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
    // Without a vocabulary nothing is named, so no prior applies.
    let no_priors = ClassPriors::default();
    let priors = vocabulary.map_or(&no_priors, |v| &v.priors);
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
            let length = i.length_m();
            if vocabulary.is_some_and(|v| v.admits_no_object(length)) {
                tracing::debug!(instance = %i.id, length, "not listed: longer than any object");
                return None;
            }
            // Named once: three completions, the published hypotheses and referring read these
            // names.
            let names = vocabulary
                .map(|v| i.name_probabilities(v, length))
                .unwrap_or_default();
            let name = vocabulary
                .and_then(|v| v.ranked(&names, 1).into_iter().next())
                .map(|(name, _)| name);
            let name = name.as_deref();
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
                let stands = name.is_some_and(|n| priors.stands_on_floor(n));
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
