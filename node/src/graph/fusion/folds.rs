//! The fold rules: instances of the map that are one object fold into the oldest of them.
//! Duplicates (similar prototypes and overlapping boxes, or two boxes filling one space),
//! fragments named alike that touch, legs under a surface and backs of seats. Each rule judges
//! only pairs with an instance that changed, pass after pass until nothing folds.

use glam::Vec3;

use super::footprint::Footprints;
use super::shapes::{as_long_as_one, boxes_alike, fitted, two_whole_boxes};
use super::{Kinds, SceneMap};
use crate::graph::instance::{bounds, cosine, Instance};
use crate::recon::boxes::DEFAULT_TRIM;
use crate::recon::round::fit_object_box;

/// The key that sorts instances oldest first: when first seen, then the order of birth (ids are
/// numbered as instances are born, so a longer id is younger). Instances born in one window tie
/// on the first: the lower id is the one the map listed first, so a user holding it keeps it
/// (ranking by observations instead let a piece seen twice take over the object the user had
/// been shown under the other id).
pub(super) fn birth_order(instance: &Instance) -> (i64, usize, &str) {
    (
        instance.first_seen_nanos,
        instance.id.len(),
        instance.id.as_str(),
    )
}

/// Whether `prototype` names an object, not structure: `same_kind` of it with itself.
pub(super) fn names_an_object(
    same_kind: &dyn Fn(&[f32], &[f32]) -> bool,
    prototype: &[f32],
) -> bool {
    !prototype.is_empty() && same_kind(prototype, prototype)
}

/// Two objects whose boxes overlap at least this much (3D IoU) are one, whatever their names
/// and prototypes: solid things do not pass through each other, and in the 200 training rooms no
/// two objects' true boxes overlap by more than 0.04 (a pillow on a bed). The map's boxes are
/// noisier than true ones, hence the margin; what overlaps this much is one object the
/// vocabulary named two ways (a trash bin listed twice, once as a desk).
pub(super) const ONE_SPACE_IOU: f64 = 0.4;

/// Two instances touch when at least this share of the smaller one's points has a point of the
/// other within the overlap radius (a seam, not an overlap).
const FRAGMENT_TOUCH: f32 = 0.02;

/// Fragments fold only when the box of both together is at most this many times as long as
/// the longest object of their name ([`Kinds::largest_side`]; the margin is for depth noise and
/// boxes fitted to a few points): two chairs side by side touch and are named alike, but
/// together they are twice as long as any chair.
pub(super) const FRAGMENT_SIDE_MARGIN: f64 = 1.5;

/// ... and at most this many times as deep (the union's shorter horizontal side) as an object of
/// their name typically is ([`Kinds::typical_depth`]): a chair in front of a bookshelf that the
/// features name bookshelf too (benchmark 15802: 0.8 m together, a bookshelf is 0.32 m deep), or
/// two bookshelves meeting at a right angle in a corner, are no fragments of one bookshelf; the
/// halves of a bed (1.4 m across, typically 1.55) are. The length's margin, read on benchmark
/// 15800-15819 and layouts 1000-1019; fresh benchmark 16200-16419 and layouts 1020-1059
/// unchanged.
pub(super) const FRAGMENT_DEPTH_MARGIN: f64 = 1.5;

/// A leg (or a side panel): an instance at most this thick along x or y (axis-aligned bounds),
/// at least [`LEG_MIN_HEIGHT_M`] tall and twice as tall as it is thick.
const LEG_MAX_THICKNESS_M: f32 = 0.2;
const LEG_MIN_HEIGHT_M: f32 = 0.3;
/// A leg's top lies at most this far below the top of the surface it carries (a table top's
/// thickness, and the top seen a little higher through depth noise) ...
const LEG_TOP_BELOW_M: f32 = 0.15;
/// ... and at most this far above it.
const LEG_TOP_ABOVE_M: f32 = 0.03;
/// A leg lies under the surface: its bounds within the surface's grown by this along x and y
/// (a top seen in part, at a slant, ends short of its legs by up to 0.2 m on the benchmark).
const LEG_INSIDE_M: f32 = 0.15;
/// What a leg carries is at least this wide along x and y.
const SURFACE_MIN_WIDTH_M: f32 = 0.3;

/// Whether an instance with bounds `leg` is a leg (or side panel) of the one with bounds
/// `surface`: thin and upright, under the surface (within its footprint) and ending just below
/// its top, reaching at least as low as the surface does. The window grouping often cuts a table's legs or a desk's side from its top (a leg is
/// a few pixels wide at the model's resolution) and the semantic model then names a lone leg
/// "chair" or "trash bin"; a chair, a bin or a cabinet under a desk is thicker, a floor lamp or
/// a chair's back rises above the top, and a bottle stands on it.
pub fn is_leg_of(leg: (Vec3, Vec3), surface: (Vec3, Vec3)) -> bool {
    let (size, surface_size) = (leg.1 - leg.0, surface.1 - surface.0);
    let thickness = size.x.min(size.y);
    let finite =
        leg.0.is_finite() && leg.1.is_finite() && surface.0.is_finite() && surface.1.is_finite();
    let upright =
        thickness <= LEG_MAX_THICKNESS_M && size.z >= LEG_MIN_HEIGHT_M && size.z >= 2.0 * thickness;
    let carries = surface_size.x.min(surface_size.y) >= SURFACE_MIN_WIDTH_M;
    let under = (0..2).all(|a| {
        leg.0[a] >= surface.0[a] - LEG_INSIDE_M && leg.1[a] <= surface.1[a] + LEG_INSIDE_M
    });
    let top = leg.1.z - surface.1.z;
    // A leg reaches at least as low as what it carries; a monitor on a desk does not.
    let reaches_down = leg.0.z <= surface.0.z + LEG_TOP_ABOVE_M;
    finite
        && upright
        && carries
        && under
        && reaches_down
        && (-LEG_TOP_BELOW_M..=LEG_TOP_ABOVE_M).contains(&top)
}

/// A back (a bed's headboard, a sofa's back): an instance at most this thick along x or y ...
const BACK_MAX_THICKNESS_M: f32 = 0.4;
/// ... lying along a side of the seat it stands behind: at least this share of the shorter of
/// its length and that side beside each other ...
const BACK_ALONG_SHARE: f32 = 0.6;
/// ... and, behind a seat seen whole (as long as one of its name, [`as_long_as_one`]), its middle
/// within the seat's extent along that side and at most this many times as long as the seat's
/// longer horizontal side: a headboard spans its bed, a backrest its seat. Two bookshelves
/// meeting in a corner (benchmark 15818) or a bookshelf 1.5 m long behind a chair 0.69 m across
/// named like it (layouts 1006) are no back and seat; a sofa's back over a piece of its seat
/// (0.5 m of it seen, benchmark 16209) is. A choice, read on benchmark 15800-15819 / 16200-16219
/// and layouts 1000-1039; fresh benchmark 16400-16419 and layouts 1040-1059 unchanged ...
const BACK_LENGTH_RATIO: f32 = 2.0;
/// ... within this of that side (a bed's middle under its pillows and duvet goes unseen or to
/// the pillows: the benchmark's beds left up to 0.9 m between foot and headboard) ...
const BACK_GAP_M: f32 = 1.0;
/// ... rising at least this far above the seat's top ...
const BACK_RISES_M: f32 = 0.15;
/// ... from no higher than this over it: a headboard stands on the bed's frame, a backrest on
/// its seat (the sim's bed, sofa and chair backs start at or below their seat's top; the margin
/// is for what hides a headboard's foot: on benchmark 7003 `realistic` a headboard seen over
/// the pillows started 0.31 m above its mattress). A box on a refrigerator's top, thin as seen
/// from below, is no back of the box on the floor under it (benchmark 8015: 1.9 m above; three
/// boxes and a refrigerator became one instance). Checked, with the other rules of its session,
/// on benchmark 12800-13019 and layouts 600-659, which no setting was read from (nothing lost).
const BACK_STARTS_ABOVE_M: f32 = 0.5;

/// Whether an instance with bounds `back` is the back of the one with bounds `seat`: thin,
/// lying along one side of the seat (mostly beside that side, at most
/// [`BACK_GAP_M`] from it, beyond the seat's middle) and rising above the seat's top from no
/// higher than [`BACK_STARTS_ABOVE_M`] over it. The window
/// grouping cuts a bed's headboard from its mattress when the pillows between them are their
/// own instances. Twin beds do not fold: a headboard lies along its own bed's end, beside the
/// other bed, not along it; a chair behind another has a back as high as its neighbour's.
/// `noise_spread` (m, 0 for a clean camera) is how much thicker than it is the back's bounds
/// are drawn by range noise: a headboard seen from 5 m through a consumer camera's noise (σ 15
/// cm) spreads over more than a metre along the view. `seat_is_whole`: the seat is as long as
/// an object of its name, so a back of it spans it ([`BACK_LENGTH_RATIO`]).
pub fn is_back_of(
    back: (Vec3, Vec3),
    seat: (Vec3, Vec3),
    noise_spread: f32,
    seat_is_whole: bool,
) -> bool {
    let finite = back.0.is_finite()
        && back.1.is_finite()
        && seat.0.is_finite()
        && seat.1.is_finite()
        && noise_spread.is_finite();
    if !finite || noise_spread < 0.0 {
        return false;
    }
    let size = back.1 - back.0;
    // The back's thin axis is its normal; its length runs along the other.
    let (normal, along) = if size.x <= size.y { (0, 1) } else { (1, 0) };
    let length = size[along];
    // The noise may make a back look deeper than it is, never longer than it is deep: a blob
    // no longer than its noisy depth stays no back.
    let thickness = (size[normal] - noise_spread).max(0.0);
    let thin = thickness <= BACK_MAX_THICKNESS_M && length >= 2.0 * size[normal];
    let beside = (back.1[along].min(seat.1[along]) - back.0[along].max(seat.0[along])).max(0.0);
    let side = seat.1[along] - seat.0[along];
    let alongside = length > 0.0 && beside >= BACK_ALONG_SHARE * length.min(side);
    let back_middle_along = (back.0[along] + back.1[along]) / 2.0;
    let centred = (seat.0[along]..=seat.1[along]).contains(&back_middle_along);
    let seat_length = (seat.1.x - seat.0.x).max(seat.1.y - seat.0.y);
    let spans_the_seat = !seat_is_whole || (centred && length <= BACK_LENGTH_RATIO * seat_length);
    // Beyond one end of the seat along the normal, within the gap (or overlapping that end).
    let middle = (seat.0[normal] + seat.1[normal]) / 2.0;
    let back_middle = (back.0[normal] + back.1[normal]) / 2.0;
    let gap = if back_middle >= middle {
        back.0[normal] - seat.1[normal]
    } else {
        seat.0[normal] - back.1[normal]
    };
    let beyond = (back_middle - middle).abs() >= (seat.1[normal] - seat.0[normal]) / 4.0;
    let stands_on_seat = back.0.z <= seat.1.z + BACK_STARTS_ABOVE_M;
    thin && alongside
        && spans_the_seat
        && beyond
        && gap <= BACK_GAP_M
        && back.1.z >= seat.1.z + BACK_RISES_M
        && stands_on_seat
}

impl SceneMap {
    /// Fold fragments of one object into the oldest of them: instances that touch (at least
    /// `FRAGMENT_TOUCH` of the smaller one's points lie next to the other's), have similar
    /// prototypes and are, by `same_kind` (the caller's vocabulary: the same best name, not
    /// structure), the same kind of thing. A bed the window grouping cut into its frame, mattress
    /// and headboard becomes one bed again; two chairs that touch stay two unless their
    /// prototypes and names agree, and a chair against a table never folds into it. Two a window
    /// saw apart ([`SceneMap::seen_apart`]) that are each as long as one object of their name and
    /// stand side by side ([`super::shapes::two_whole_boxes`]: two bookshelves of a row) are
    /// two objects, not fragments. A leg under a
    /// surface ([`is_leg_of`]) folds whatever it is named, both being objects (`same_kind` of a
    /// prototype with itself: not structure). Returns (absorbed, survivor) id pairs.
    pub fn fold_fragments(&mut self, kinds: &impl Kinds) -> Vec<(String, String)> {
        let every = vec![true; self.instances.len()];
        self.fold_fragments_of(kinds, &every)
    }

    /// [`SceneMap::fold_fragments`] over the pairs with at least one instance `touched` marks
    /// ([`SceneMap::fold_pairs`]).
    pub(super) fn fold_fragments_of(
        &mut self,
        kinds: &impl Kinds,
        touched: &[bool],
    ) -> Vec<(String, String)> {
        let p = self.params;
        let same_kind = |a: &[f32], b: &[f32]| kinds.same_kind(a, b);
        let mut keep = vec![true; self.instances.len()];
        let is_object = |prototype: &[f32]| names_an_object(&same_kind, prototype);
        // By index, once: instances keep their places while the pairs are judged.
        let apart = self.seen_apart_indices();
        let folded = self.fold_pairs(&mut keep, touched, |instances, footprints, a, b| {
            let (pa, pb) = (&instances[a].prototype, &instances[b].prototype);
            let (bounds_a, bounds_b) = (footprints.bounds[a], footprints.bounds[b]);
            if is_object(pa)
                && is_object(pb)
                && (is_leg_of(bounds_a, bounds_b) || is_leg_of(bounds_b, bounds_a))
            {
                tracing::debug!(a = %instances[a].id, b = %instances[b].id, "fold rule: a leg");
                return true;
            }
            if pa.is_empty() || pb.is_empty() || !same_kind(pa, pb) {
                return false;
            }
            let (back_a, spread_a) = footprints.back_bounds(instances, a);
            let (back_b, spread_b) = footprints.back_bounds(instances, b);
            let whole = |bounds: (Vec3, Vec3), prototype: &[f32]| {
                let size = bounds.1 - bounds.0;
                as_long_as_one(
                    f64::from(size.x.max(size.y)),
                    kinds.typical_length(prototype),
                )
            };
            if is_back_of(back_a, bounds_b, spread_a, whole(bounds_b, pb))
                || is_back_of(back_b, bounds_a, spread_b, whole(bounds_a, pa))
            {
                tracing::debug!(a = %instances[a].id, b = %instances[b].id, "fold rule: a back");
                return true;
            }
            let (ma, mb) = (&instances[a].gaussians.means, &instances[b].gaussians.means);
            let seen_apart = apart.contains(&(a.min(b), a.max(b)));
            let fragments = cosine(pa, pb) >= p.duplicate_similarity
                && footprints.overlap(instances, a, b) >= FRAGMENT_TOUCH
                && kinds.largest_side(pa).is_none_or(|side| {
                    let both: Vec<Vec3> = ma.iter().chain(mb).copied().collect();
                    let union = fit_object_box(&both, DEFAULT_TRIM);
                    let length = union.size.x.max(union.size.y);
                    let depth = union.size.x.min(union.size.y);
                    length <= FRAGMENT_SIDE_MARGIN * side
                        && kinds
                            .typical_depth(pa)
                            .is_none_or(|typical| depth <= FRAGMENT_DEPTH_MARGIN * typical)
                        // Seen apart, each as long as one: two objects of a row, not fragments.
                        && !(seen_apart && {
                            let (box_a, box_b) = (fitted(ma), fitted(mb));
                            boxes_alike(&box_a, &box_b)
                                && two_whole_boxes(
                                    &box_a,
                                    &box_b,
                                    length,
                                    kinds.typical_length(pa),
                                    side,
                                )
                        })
                });
            if fragments {
                tracing::debug!(a = %instances[a].id, b = %instances[b].id, "fold rule: fragments");
            }
            fragments
        });
        self.retain_marked(&keep);
        folded
    }

    /// Every pair of live instances with at least one of them `touched` (changed since the pair
    /// was last judged), oldest first (so everything folds into the instance the user saw
    /// first): where `one_object` says so, the younger is absorbed into the older and marked dead
    /// in `keep`. Then pass after pass over the pairs of the last pass's survivors (they changed
    /// after some of their pairs were judged) until a pass folds nothing. Point footprints are
    /// built only when `one_object` asks for them, and again after their instance absorbs
    /// another; bounds and boxes afresh in the pass after. Returns (absorbed, survivor) id pairs.
    fn fold_pairs(
        &mut self,
        keep: &mut [bool],
        touched: &[bool],
        mut one_object: impl FnMut(&[Instance], &mut Footprints, usize, usize) -> bool,
    ) -> Vec<(String, String)> {
        let p = self.params;
        let n = self.instances.len();
        let mut footprints = Footprints {
            voxel: p.voxel,
            built: (0..n).map(|_| None).collect(),
            bounds: self
                .instances
                .iter()
                .map(|i| bounds(&i.gaussians))
                .collect(),
            spread: (0..n).map(|_| None).collect(),
            boxes: (0..n).map(|_| None).collect(),
        };
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by_key(|&i| birth_order(&self.instances[i]));
        let mut folded = Vec::new();
        let mut touched = touched.to_vec();
        loop {
            let mut grew = vec![false; n];
            for (position, &a) in order.iter().enumerate() {
                if !keep[a] {
                    continue;
                }
                for &b in &order[position + 1..] {
                    if !keep[b] || !(touched[a] || touched[b]) {
                        continue;
                    }
                    if one_object(&self.instances, &mut footprints, a, b) {
                        let absorbed = self.instances[b].clone();
                        self.instances[a].absorb(&absorbed, p);
                        footprints.built[a] = None;
                        footprints.spread[a] = None;
                        let ((lo_a, hi_a), (lo_b, hi_b)) =
                            (footprints.bounds[a], footprints.bounds[b]);
                        footprints.bounds[a] = (lo_a.min(lo_b), hi_a.max(hi_b));
                        keep[b] = false;
                        grew[a] = true;
                        folded.push((absorbed.id, self.instances[a].id.clone()));
                    }
                }
            }
            if !grew.contains(&true) {
                return folded;
            }
            for (k, &changed) in grew.iter().enumerate() {
                if changed {
                    footprints.bounds[k] = bounds(&self.instances[k].gaussians);
                    footprints.boxes[k] = None;
                }
            }
            touched = grew;
        }
    }

    /// Fold instances that are one object (similar prototypes and overlapping boxes, or two
    /// objects' boxes filling one space, [`ONE_SPACE_IOU`]) into the oldest of them; `keep` marks
    /// the instances still alive and is updated. Returns (absorbed, survivor) id pairs.
    pub(super) fn fold_duplicates(
        &mut self,
        keep: &mut [bool],
        touched: &[bool],
        same_kind: &dyn Fn(&[f32], &[f32]) -> bool,
    ) -> Vec<(String, String)> {
        let p = self.params;
        let is_object = |prototype: &[f32]| names_an_object(same_kind, prototype);
        // By index, once: instances keep their places while the pairs are judged.
        let apart = self.seen_apart_indices();
        self.fold_pairs(keep, touched, |instances, footprints, a, b| {
            if apart.contains(&(a.min(b), a.max(b))) {
                return false;
            }
            let (pa, pb) = (&instances[a].prototype, &instances[b].prototype);
            let similar = !pa.is_empty()
                && !pb.is_empty()
                && cosine(pa, pb) >= p.duplicate_similarity
                && same_kind(pa, pb);
            if similar && p.duplicate_iou <= 0.0 {
                // Prototypes alone decide.
                return true;
            }
            let objects = similar || (is_object(pa) && is_object(pb));
            if !objects || footprints.far_apart(a, b) {
                return false;
            }
            let box_a = footprints.oriented_box(instances, a);
            let box_b = footprints.oriented_box(instances, b);
            let iou = box_a.iou(&box_b);
            if iou >= ONE_SPACE_IOU {
                tracing::debug!(a = %instances[a].id, b = %instances[b].id, iou, "fold rule: one space");
                return true;
            }
            // Point footprints only where boxes alone do not decide.
            let duplicate =
                similar && (iou >= p.duplicate_iou || footprints.overlap(instances, a, b) >= 0.5);
            if duplicate {
                tracing::debug!(a = %instances[a].id, b = %instances[b].id, iou, "fold rule: duplicates");
            }
            duplicate
        })
    }
}
