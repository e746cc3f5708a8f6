use super::folds::{is_back_of, is_leg_of, ONE_SPACE_IOU};
use super::footprint::{share_bounds, Footprint, Footprints, BACK_SPREAD_SHARE};
use super::*;
use crate::graph::instance::bounds;
use crate::recon::boxes::OrientedBox;
use crate::recon::gaussians::Gaussians;
use glam::Quat;
use rand::{Rng, SeedableRng};

/// Small opaque grey Gaussians at `points`: an instance for the map's geometry.
pub(super) fn gaussians_at(points: impl IntoIterator<Item = Vec3>) -> Gaussians {
    let mut g = Gaussians::with_dims(0, 0);
    for p in points {
        g.push(
            p,
            0.9,
            Vec3::splat(0.01),
            Quat::IDENTITY,
            Vec3::splat(0.5),
            &[],
            &[],
        );
    }
    g
}

/// Points along a random segment with a little spread: thin diagonal sets are where a fitted
/// box pokes out of the points' axis-aligned bounds the most.
fn rod(rng: &mut rand_chacha::ChaCha8Rng, centre: Vec3) -> Gaussians {
    let half = Vec3::new(
        rng.random_range(-1.0..1.0),
        rng.random_range(-1.0..1.0),
        0.0,
    ) * rng.random_range(0.05..1.5);
    gaussians_at((0..60).map(|k| {
        let t = k as f32 / 59.0 * 2.0 - 1.0;
        let jitter = Vec3::new(
            rng.random_range(-0.02..0.02),
            rng.random_range(-0.02..0.02),
            rng.random_range(0.0..0.3),
        );
        centre + half * t + jitter
    }))
}

#[test]
fn no_two_objects_of_the_training_rooms_fill_one_space() {
    // ONE_SPACE_IOU against the data: the largest 3D IoU of two objects' true boxes in the
    // first 200 training rooms is a small share of it.
    let mut largest = 0.0f64;
    for room in super::super::amodal::training_rooms() {
        for (k, (_, a)) in room.iter().enumerate() {
            for (_, b) in &room[k + 1..] {
                largest = largest.max(a.iou(b));
            }
        }
    }
    assert!(largest > 0.0, "some objects touch (a pillow on a bed)");
    assert!(largest < ONE_SPACE_IOU / 4.0, "{largest}");
}

#[test]
fn fragments_born_in_one_window_fold_into_the_lower_id_however_often_the_other_was_seen() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let piece = rod(&mut rng, Vec3::new(2.0, 2.6, 0.4));
    let fragment = |id: &str, observations: u32| Instance {
        id: id.to_owned(),
        gaussians: piece.clone(),
        prototype: vec![1.0, 0.0, 0.0],
        prototype_weight: 1.0,
        confidence: 0.5,
        observations,
        first_seen_nanos: 1_000,
        last_seen_nanos: 2_000,
        viewpoint: None,
        viewpoint_weight: 0.0,
        range_noise_m: 0.0,
        range_noise_weight: 0.0,
        seen_free: Vec::new(),
    };
    // Two pieces of one chair born in one window; the younger was seen again by the next
    // window, the older is the one the map listed. Ids compare in birth order (010 > 009).
    for (older, younger) in [
        ("inst_000002", "inst_000003"),
        ("inst_000009", "inst_000010"),
    ] {
        let mut map = SceneMap::new(FusionParams::default());
        map.instances = vec![fragment(younger, 2), fragment(older, 1)];
        let folded = map.fold_fragments(&|_: &[f32], _: &[f32]| true);
        assert_eq!(folded, vec![(younger.to_owned(), older.to_owned())]);
        assert_eq!(map.instances.len(), 1);
        assert_eq!(map.instances[0].id, older);
    }
}

#[test]
fn a_leg_needs_finite_bounds_an_upright_shape_and_a_surface_over_it() {
    let top = (Vec3::new(-0.4, -0.3, 0.72), Vec3::new(0.4, 0.3, 0.75));
    let leg = (Vec3::new(0.3, 0.2, 0.0), Vec3::new(0.35, 0.25, 0.7));
    assert!(is_leg_of(leg, top));
    assert!(!is_leg_of(top, leg), "the top is no leg of its leg");
    let empty = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    let nan = (Vec3::splat(f32::NAN), Vec3::splat(f32::NAN));
    for bad in [empty, nan] {
        assert!(!is_leg_of(bad, top) && !is_leg_of(leg, bad));
    }
    // A point (one Gaussian) and a flat stub are not upright; a leg ending a hand below the
    // top carries something else; a leg poking out beside the top is not under it.
    let point = (Vec3::new(0.3, 0.2, 0.5), Vec3::new(0.3, 0.2, 0.5));
    let stub = (Vec3::new(0.3, 0.2, 0.0), Vec3::new(0.35, 0.25, 0.05));
    let short = (Vec3::new(0.3, 0.2, 0.0), Vec3::new(0.35, 0.25, 0.5));
    let beside = (Vec3::new(0.52, 0.2, 0.0), Vec3::new(0.57, 0.25, 0.7));
    // A monitor standing on a desk whose points reach the floor: thin, upright, under the
    // desk's top and ending near the top of its bounds (the monitor's own), but it does not
    // reach down.
    let desk = (Vec3::new(-0.4, -0.3, 0.0), Vec3::new(0.4, 0.3, 1.2));
    let monitor = (Vec3::new(-0.25, 0.0, 0.75), Vec3::new(0.25, 0.05, 1.2));
    assert!(!is_leg_of(monitor, desk));
    assert!(is_leg_of(
        (Vec3::new(-0.25, 0.0, 0.0), Vec3::new(0.25, 0.05, 1.2)),
        desk
    ));
    for not_a_leg in [point, stub, short, beside] {
        assert!(!is_leg_of(not_a_leg, top), "{not_a_leg:?}");
    }
}

#[test]
fn a_headboard_folds_into_its_bed_but_not_into_the_twin_bed_beside_it() {
    // The foot end of a bed seen (x 5.1-6.6), its headboard 0.85 m beyond (x 7.45-7.6),
    // wider than the part of the mattress seen, rising above it.
    let mattress = (Vec3::new(5.1, 1.9, 0.0), Vec3::new(6.6, 2.6, 0.48));
    let headboard = (Vec3::new(7.45, 1.1, 0.48), Vec3::new(7.6, 3.0, 1.2));
    assert!(is_back_of(headboard, mattress, 0.0, false));
    assert!(
        !is_back_of(mattress, headboard, 0.0, false),
        "the mattress is no back"
    );
    // A twin bed beside it (y 3.4-5.0): the headboard lies along its own bed, not this one.
    let twin = (Vec3::new(5.6, 3.4, 0.0), Vec3::new(7.5, 5.0, 0.48));
    assert!(!is_back_of(headboard, twin, 0.0, false));
    // A chair in the row behind another: its back is no higher than the other chair.
    let chair = (Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.45, 0.45, 0.9));
    let back_of_the_chair_behind = (Vec3::new(0.0, 0.7, 0.45), Vec3::new(0.45, 0.75, 0.9));
    assert!(!is_back_of(back_of_the_chair_behind, chair, 0.0, false));
    // A box on a refrigerator's top (2.18 m up), seen thin from below, beside a box on the
    // floor: it starts far above that box's top, so it is no back of it.
    let floor_box = (Vec3::new(4.2, 4.7, 0.0), Vec3::new(4.5, 4.95, 0.25));
    let box_on_top = (Vec3::new(4.25, 5.4, 2.18), Vec3::new(4.6, 5.5, 2.33));
    assert!(!is_back_of(box_on_top, floor_box, 0.0, false));
    // Farther than the gap, in the seat's middle, or without finite bounds: no back.
    let far = (Vec3::new(7.7, 1.1, 0.48), Vec3::new(7.85, 3.0, 1.2));
    let across_the_middle = (Vec3::new(5.8, 1.1, 0.48), Vec3::new(5.95, 3.0, 1.2));
    assert!(
        !is_back_of(far, mattress, 0.0, false)
            && !is_back_of(across_the_middle, mattress, 0.0, false)
    );
    let nan = (Vec3::splat(f32::NAN), Vec3::splat(f32::NAN));
    let empty = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for bad in [nan, empty] {
        assert!(!is_back_of(bad, mattress, 0.0, false) && !is_back_of(headboard, bad, 0.0, false));
    }
}

#[test]
fn a_bookshelf_at_a_right_angle_or_behind_a_chair_is_no_back_of_it_but_a_sofas_back_over_a_piece_is(
) {
    // Benchmark 15818: two bookshelves meeting in a corner, each seen whole. The taller one
    // (1.84 m) is thin and rises above the shorter one's top, lying along its 0.3 m end, but it
    // runs on past that end: its middle lies beyond the shorter one, as no headboard lies
    // beside its bed.
    let tall = (Vec3::new(0.13, 0.02, 0.0), Vec3::new(1.06, 0.35, 1.84));
    let short = (Vec3::new(0.02, 0.34, 0.0), Vec3::new(0.32, 1.17, 1.52));
    assert!(!is_back_of(tall, short, 0.0, true));
    // The same tall one centred on the short one's end: a back by every test.
    let centred = (Vec3::new(-0.3, 0.02, 0.0), Vec3::new(0.63, 0.35, 1.84));
    assert!(is_back_of(centred, short, 0.0, true));
    // Layouts 1006: a bookshelf 1.5 m long, 0.25 m behind a chair 0.69 m across that the
    // features name bookshelf too: more than twice as long as the chair, so no back of it.
    let chair = (Vec3::new(4.6, 3.04, 0.0), Vec3::new(5.28, 3.65, 0.76));
    let shelf = (Vec3::new(5.53, 2.72, 0.0), Vec3::new(5.91, 4.22, 2.08));
    assert!(!is_back_of(shelf, chair, 0.0, true));
    let backrest = (Vec3::new(5.53, 3.0, 0.0), Vec3::new(5.73, 3.7, 1.2));
    assert!(is_back_of(backrest, chair, 0.0, true));
    // Benchmark 16209: a sofa's back 1.87 m long over a piece of its seat 0.5 m long, off to one
    // side: a piece of a seat may lie anywhere under its back.
    let sofa_back = (Vec3::new(1.58, 6.57, 0.48), Vec3::new(3.45, 6.58, 0.99));
    let seat_piece = (Vec3::new(2.5, 5.68, 0.0), Vec3::new(2.99, 5.93, 0.53));
    assert!(is_back_of(sofa_back, seat_piece, 0.0, false));
    assert!(!is_back_of(sofa_back, seat_piece, 0.0, true));
    // A bed seen from its foot end, 0.7 m of its width: its headboard spans it, whole or not.
    let mattress = (Vec3::new(5.1, 1.9, 0.0), Vec3::new(6.6, 2.6, 0.48));
    let headboard = (Vec3::new(7.45, 1.1, 0.48), Vec3::new(7.6, 3.0, 1.2));
    assert!(is_back_of(headboard, mattress, 0.0, true));
}

#[test]
fn a_noisy_back_is_judged_by_its_central_points_less_the_noise_and_degenerate_sets_are_no_back() {
    // 100 points along x (0..99 cm) and two non-finite ones: 5% each side left out.
    let mut points: Vec<Vec3> = (0..100)
        .map(|i| Vec3::new(i as f32 * 0.01, 0.0, 0.0))
        .collect();
    points.push(Vec3::NAN);
    points.push(Vec3::new(f32::INFINITY, 0.0, 0.0));
    let (lo, hi) = share_bounds(&points, BACK_SPREAD_SHARE);
    assert!(
        (lo.x - 0.05).abs() < 1e-6 && (hi.x - 0.94).abs() < 1e-6,
        "{lo} {hi}"
    );
    let single = share_bounds(&[Vec3::ONE], BACK_SPREAD_SHARE);
    assert_eq!(single, (Vec3::ONE, Vec3::ONE));
    let empty = share_bounds(&[Vec3::NAN], BACK_SPREAD_SHARE);
    assert_eq!(empty, (Vec3::INFINITY, Vec3::NEG_INFINITY));
    // A headboard 0.9 m deep through noise: a back only with the noise's spread allowed for.
    let mattress = (Vec3::new(5.1, 1.9, 0.0), Vec3::new(6.6, 2.6, 0.48));
    let spread_headboard = (Vec3::new(7.1, 1.1, 0.48), Vec3::new(8.0, 3.0, 1.2));
    assert!(!is_back_of(spread_headboard, mattress, 0.0, false));
    assert!(is_back_of(spread_headboard, mattress, 0.6, false));
    // Noise never makes a back of what is no back: the mattress, or a chair's neighbour.
    assert!(!is_back_of(mattress, spread_headboard, 0.6, false));
    // A lamp's shade above another lamp, 21 cm across each way: the noise makes it thin,
    // never long.
    let lamp = (Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.25, 0.25, 0.52));
    let shade = (Vec3::new(0.02, 0.3, 0.7), Vec3::new(0.234, 0.51, 0.83));
    assert!(!is_back_of(shade, lamp, 0.18, false));
    for bad in [f32::NAN, -0.1, f32::INFINITY] {
        assert!(!is_back_of(spread_headboard, mattress, bad, false), "{bad}");
    }
    assert!(!is_back_of(empty, mattress, 0.6, false));
}

#[test]
fn pairs_judged_far_apart_never_have_intersecting_boxes_or_touching_footprints() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let (mut pruned, mut trials) = (0, 0);
    for _ in 0..400 {
        let offset = Vec3::new(
            rng.random_range(-4.0..4.0),
            rng.random_range(-4.0..4.0),
            0.0,
        );
        let (a, b) = (rod(&mut rng, Vec3::ZERO), rod(&mut rng, offset));
        let footprints = Footprints {
            voxel: 0.05,
            built: vec![None, None],
            bounds: vec![bounds(&a), bounds(&b)],
            spread: vec![None, None],
            boxes: vec![None, None],
        };
        if !footprints.far_apart(0, 1) {
            continue;
        }
        pruned += 1;
        let (box_a, box_b) = (
            OrientedBox::fit(&a.means, crate::recon::boxes::DEFAULT_TRIM),
            OrientedBox::fit(&b.means, crate::recon::boxes::DEFAULT_TRIM),
        );
        assert_eq!(box_a.iou(&box_b), 0.0, "boxes of a far pair intersect");
        let (fa, fb) = (Footprint::new(&a, 0.05), Footprint::new(&b, 0.05));
        assert_eq!(fa.overlap(&fb, 1.5 * fa.spacing.max(fb.spacing)), 0.0);
        trials += 1;
    }
    // The check must have pruned something, and not everything.
    assert!(pruned > 50 && pruned < 400, "{pruned} of 400 pruned");
    assert_eq!(trials, pruned);
}

/// Two objects side by side, each a window instance of its own.
fn sighting(gaussians: &Gaussians, prototype: [f32; 3]) -> crate::frame::WindowInstance {
    crate::frame::WindowInstance {
        gaussians: gaussians.clone(),
        prototype: prototype.to_vec(),
        support: gaussians.len(),
    }
}

#[test]
fn instances_a_window_saw_apart_are_not_folded_when_their_boxes_grow_into_one_space() {
    let a = rod(
        &mut rand_chacha::ChaCha8Rng::seed_from_u64(3),
        Vec3::new(2.0, 2.0, 0.4),
    );
    let b = rod(
        &mut rand_chacha::ChaCha8Rng::seed_from_u64(4),
        Vec3::new(4.0, 2.0, 0.4),
    );
    // B's points, later, where A is (range noise, a sighting that spanned both): one space.
    let grown = rod(
        &mut rand_chacha::ChaCha8Rng::seed_from_u64(3),
        Vec3::new(2.02, 2.0, 0.4),
    );
    let (pa, pb) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
    let run = |seen_apart_first: bool| {
        let mut map = SceneMap::new(FusionParams::default());
        map.fuse(vec![sighting(&a, pa)], &[], 1).unwrap();
        map.fuse(vec![sighting(&b, pb)], &[], 2).unwrap();
        assert_eq!(map.instances.len(), 2);
        if seen_apart_first {
            // One window sees both already-mapped objects, as two.
            map.fuse(vec![sighting(&a, pa), sighting(&b, pb)], &[], 3)
                .unwrap();
        }
        let (ida, idb) = (map.instances[0].id.clone(), map.instances[1].id.clone());
        assert_eq!(map.seen_apart(&ida, &idb), seen_apart_first);
        map.instances[1].gaussians = grown.clone();
        map.fuse(vec![sighting(&a, pa)], &[], 4).unwrap();
        map
    };
    // Without the evidence the boxes filling one space fold; with it both stay.
    assert_eq!(run(false).instances.len(), 1);
    let kept = run(true);
    assert_eq!(kept.instances.len(), 2);
    // The evidence is kept with the map and survives a snapshot.
    let restored =
        crate::graph::persist::from_bytes(&crate::graph::persist::to_bytes(&kept), kept.params)
            .unwrap();
    assert_eq!(restored.seen_apart, kept.seen_apart);
    assert_eq!(restored.seen_apart.len(), 1);
}

/// The visible faces (top and front, y = 0) of a box from `x0` to `x1`, 0.4 m deep and tall,
/// points 2 cm apart, keeping those `keep` accepts.
fn box_faces(x0: f32, x1: f32, keep: impl Fn(Vec3) -> bool) -> Gaussians {
    let steps =
        |a: f32, b: f32| (0..=((b - a) / 0.02).round() as usize).map(move |k| a + 0.02 * k as f32);
    let top = steps(x0, x1).flat_map(|x| steps(0.0, 0.4).map(move |y| Vec3::new(x, y, 0.4)));
    let front = steps(x0, x1).flat_map(|x| steps(0.0, 0.4).map(move |z| Vec3::new(x, 0.0, z)));
    gaussians_at(top.chain(front).filter(|p| keep(*p)))
}

#[test]
fn a_sighting_that_grazes_a_neighbour_reveals_no_duplicate_one_that_spans_it_does() {
    // Two boxes of a row, 2 cm apart, alike, born as two in one window.
    let row = |window: Vec<Gaussians>| {
        let mut map = SceneMap::new(FusionParams::default());
        let both = [
            box_faces(0.0, 0.4, |_| true),
            box_faces(0.42, 0.82, |_| true),
        ];
        map.fuse(
            both.iter().map(|g| sighting(g, [1.0, 0.0, 0.0])).collect(),
            &[],
            1,
        )
        .unwrap();
        assert_eq!(map.instances.len(), 2);
        let sightings = window
            .iter()
            .map(|g| sighting(g, [1.0, 0.0, 0.0]))
            .collect();
        map.fuse(sightings, &[], 2).unwrap();
        map
    };
    // The first box's side next to the second: a fifth of it lies within the overlap radius of
    // the second's face, enough for the gate, but it covers little of the second.
    let grazing = box_faces(0.0, 0.4, |p| p.x >= 0.3);
    assert_eq!(row(vec![grazing]).instances.len(), 2);
    // One window instance over both boxes (the window grouped them together): one object.
    let spanning = box_faces(0.0, 0.82, |_| true);
    assert_eq!(row(vec![spanning]).instances.len(), 1);
}

/// Points on the faces of an axis-aligned box (`lo`..`hi`) every 4 cm, as a map holds them.
pub(in crate::graph::fusion) fn block(lo: Vec3, hi: Vec3) -> Gaussians {
    let steps = ((hi - lo) / 0.04).ceil().as_uvec3();
    let grid = (0..=steps.x)
        .flat_map(|i| (0..=steps.y).flat_map(move |j| (0..=steps.z).map(move |k| (i, j, k))));
    gaussians_at(grid.filter_map(|(i, j, k)| {
        let on_face = [
            i == 0 || i == steps.x,
            j == 0 || j == steps.y,
            k == 0 || k == steps.z,
        ];
        let t = Vec3::new(i as f32, j as f32, k as f32) / steps.as_vec3().max(Vec3::ONE);
        on_face.contains(&true).then(|| lo + (hi - lo) * t)
    }))
}

#[test]
fn a_footprint_queried_again_answers_as_a_fresh_one_at_every_radius() {
    // Two interleaved rows, each point 5 cm from the other row's nearest: covered at a radius of
    // 6 cm, not at 4 cm. The grid kept from one query must not answer the next at another radius.
    let row =
        |x0: f32| gaussians_at((0..40).map(move |k| Vec3::new(x0 + k as f32 * 0.1, 0.0, 0.0)));
    let (a, b) = (row(0.0), row(0.05));
    let fresh =
        |radius: f32| Footprint::new(&a, 0.01).covered_by(&Footprint::new(&b, 0.01), radius);
    assert_eq!(fresh(0.06), 1.0);
    assert_eq!(fresh(0.04), 0.0);
    let (fa, fb) = (Footprint::new(&a, 0.01), Footprint::new(&b, 0.01));
    for radius in [0.06, 0.06, 0.04, 0.06, 0.04, 0.04] {
        assert_eq!(fa.covered_by(&fb, radius), fresh(radius), "radius {radius}");
    }
}
