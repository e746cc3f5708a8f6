#![allow(clippy::unwrap_used)]
//! Generated referring expressions: every relation type occurs, and each expression means exactly
//! its targets, re-checked for every relation by a second, plain implementation of Sr3D's rules on
//! the scene's boxes (and placement support where the scene records it), independent of the
//! generator's margins: the targets satisfy the relation, every other object of their class does
//! not.

use std::collections::BTreeMap;

use glam::{DMat3, DQuat, DVec3};
use groupforward_sim::procedural::{generate, Split};
use groupforward_sim::referring::ViewPose;
use groupforward_sim::referring::{
    color_name, geometry as object_geometry, scene_expressions, Expression, Geometry, Relation,
};
use groupforward_sim::render::Scene;

/// A point in the camera frame of `view` (REP-103 optical: x right, y down, z forward).
fn in_view(view: &ViewPose, p: DVec3) -> DVec3 {
    let camera_from_world = DMat3::from_quat(DQuat::from_array(view.orientation)).transpose();
    camera_from_world * (p - DVec3::from_array(view.position))
}

/// Horizontal angle in the view, degrees, positive to the right.
fn bearing_deg(view: &ViewPose, p: DVec3) -> f64 {
    let c = in_view(view, p);
    (c.x / c.z).atan().to_degrees()
}

/// Sr3D "above" on boxes: footprints overlap, the base no lower than the anchor's top less the
/// contact tolerance, the centre at least 6 cm higher.
fn is_above(t: &Geometry, a: &Geometry) -> bool {
    let overlaps = t.lo.x < a.hi.x && a.lo.x < t.hi.x && t.lo.y < a.hi.y && a.lo.y < t.hi.y;
    overlaps && t.lo.z >= a.hi.z - 0.15 && t.center().z >= a.center().z + 0.06
}

/// Sr3D "between" in the floor plane: the centre projects onto the middle 70% of the segment
/// joining the anchors' centres and lies within half a metre of it.
fn is_between(t: &Geometry, a: &Geometry, b: &Geometry) -> bool {
    let (pa, pb, pt) = (
        a.center().truncate(),
        b.center().truncate(),
        t.center().truncate(),
    );
    let ab = pb - pa;
    let s = (pt - pa).dot(ab) / ab.length_squared();
    (0.15..=0.85).contains(&s) && (pt - (pa + s * ab)).length() <= 0.5
}

fn benchmark(count: u64) -> Vec<(Scene, Vec<Expression>)> {
    (0..count)
        .map(|i| {
            let file = generate(Split::Benchmark, i).unwrap();
            (file.build().unwrap(), scene_expressions(&file).unwrap())
        })
        .collect()
}

fn geometry(scene: &Scene, id: u16) -> Geometry {
    object_geometry(scene.objects.iter().find(|o| o.instance_id == id).unwrap())
}

#[test]
fn every_relation_type_is_generated() {
    let mut counts: BTreeMap<Relation, usize> = BTreeMap::new();
    let mut total = 0;
    for (_, expressions) in benchmark(30) {
        for e in expressions {
            *counts.entry(e.relation).or_default() += 1;
            total += 1;
        }
    }
    eprintln!("{total} expressions: {counts:?}");
    use Relation::*;
    for relation in [
        Class, Closest, Farthest, Above, Below, On, Supporting, Left, Right, Front, Behind,
        Between, Biggest, Smallest, Tallest, Highest, Lowest, Leftmost, Rightmost, Color, Function,
        TwoHop,
    ] {
        assert!(
            counts.get(&relation).copied().unwrap_or(0) > 0,
            "no {relation:?}"
        );
    }
}

#[test]
fn expressions_mean_exactly_their_targets() {
    for (scene, expressions) in benchmark(30) {
        for e in &expressions {
            assert!(
                !e.targets.is_empty() && e.cardinality == e.targets.len(),
                "{e:?}"
            );
            assert_eq!(e.view_dependent, e.view.is_some(), "{}", e.text);
            let targets: Vec<Geometry> = e.targets.iter().map(|id| geometry(&scene, *id)).collect();
            let same_class: Vec<Geometry> = scene
                .objects
                .iter()
                .map(object_geometry)
                .filter(|g| g.class == e.target_class)
                .collect();
            for t in &targets {
                assert!(
                    e.target_class.is_empty() || t.class == e.target_class,
                    "{}",
                    e.text
                );
            }
            match e.relation {
                Relation::Class => assert_eq!(e.targets.len(), same_class.len(), "{}", e.text),
                Relation::On => {
                    // Placement ground truth: each target stands on an anchor-class object, no
                    // other object of the class does.
                    let anchor_class = geometry(&scene, e.anchors[0]).class;
                    for g in &same_class {
                        let object = scene
                            .objects
                            .iter()
                            .find(|o| o.instance_id == g.id)
                            .unwrap();
                        let on_anchor = object
                            .support
                            .is_some_and(|s| geometry(&scene, s).class == anchor_class);
                        assert_eq!(on_anchor, e.targets.contains(&g.id), "{}", e.text);
                    }
                }
                Relation::Closest | Relation::Farthest => {
                    let anchor = geometry(&scene, e.anchors[0]).center();
                    let d = |g: &Geometry| (g.center() - anchor).length();
                    let target = d(&targets[0]);
                    for g in same_class.iter().filter(|g| g.id != targets[0].id) {
                        if e.relation == Relation::Closest {
                            assert!(d(g) >= target + 0.2, "{}", e.text);
                        } else {
                            assert!(d(g) <= target - 0.2, "{}", e.text);
                        }
                    }
                }
                Relation::TwoHop => {
                    // The anchor is the one of its class the inner words pick against the far
                    // object, and the target the one of its class the outer words pick against
                    // the anchor; every other is at least Sr3D's 0.2 m behind.
                    let (anchor, far) = (
                        geometry(&scene, e.anchors[0]),
                        geometry(&scene, e.anchors[1]),
                    );
                    let (outer, inner) = e
                        .text
                        .split_once(&format!(" the {} ", anchor.class))
                        .unwrap();
                    let picks = |words: &str, of: &Geometry, among: &[Geometry], by: &Geometry| {
                        let d = |g: &Geometry| (g.center() - by.center()).length();
                        among.iter().filter(|g| g.id != of.id).all(|g| {
                            if words.contains("closest to") {
                                d(g) >= d(of) + 0.2
                            } else {
                                assert!(words.contains("farthest from"), "{}", e.text);
                                d(g) <= d(of) - 0.2
                            }
                        })
                    };
                    let anchors_class: Vec<Geometry> = scene
                        .objects
                        .iter()
                        .map(object_geometry)
                        .filter(|g| g.class == anchor.class)
                        .collect();
                    assert!(anchors_class.len() >= 2, "{}", e.text);
                    assert!(picks(inner, &anchor, &anchors_class, &far), "{}", e.text);
                    assert!(
                        picks(outer, &targets[0], &same_class, &anchor),
                        "{}",
                        e.text
                    );
                }
                Relation::Biggest | Relation::Smallest => {
                    for g in same_class.iter().filter(|g| g.id != targets[0].id) {
                        let ratio = targets[0].volume() / g.volume();
                        if e.relation == Relation::Biggest {
                            assert!(ratio >= 1.25, "{}", e.text);
                        } else {
                            assert!(ratio <= 1.0 / 1.25, "{}", e.text);
                        }
                    }
                }
                Relation::Color => {
                    let word = color_name(targets[0].color);
                    assert!(e.text.contains(word), "{}", e.text);
                    for g in same_class.iter().filter(|g| g.id != targets[0].id) {
                        assert_ne!(color_name(g.color), word, "{}", e.text);
                    }
                }
                Relation::Function => {
                    let classes = groupforward_sim::library::classes();
                    let affordance = e.text.rsplit("you can ").next().unwrap();
                    for g in scene.objects.iter().map(object_geometry) {
                        let can = classes
                            .iter()
                            .any(|c| c.name == g.class && c.affordances.contains(&affordance));
                        assert_eq!(can, e.targets.contains(&g.id), "{}", e.text);
                    }
                }
                Relation::Supporting => {
                    // Placement ground truth: each target carries an anchor-class object.
                    let anchor_class = geometry(&scene, e.anchors[0]).class;
                    for g in &same_class {
                        let carries = scene.objects.iter().any(|o| {
                            o.support == Some(g.id)
                                && geometry(&scene, o.instance_id).class == anchor_class
                        });
                        assert_eq!(carries, e.targets.contains(&g.id), "{}", e.text);
                    }
                }
                Relation::Above | Relation::Below => {
                    let anchor_class = geometry(&scene, e.anchors[0]).class;
                    let anchors: Vec<Geometry> = scene
                        .objects
                        .iter()
                        .map(object_geometry)
                        .filter(|g| g.class == anchor_class)
                        .collect();
                    for g in &same_class {
                        let holds = anchors.iter().any(|a| {
                            if e.relation == Relation::Above {
                                is_above(g, a)
                            } else {
                                is_above(a, g)
                            }
                        });
                        assert_eq!(holds, e.targets.contains(&g.id), "{}", e.text);
                    }
                }
                Relation::Left | Relation::Right | Relation::Front | Relation::Behind => {
                    let view = e.view.unwrap();
                    let anchor = geometry(&scene, e.anchors[0]);
                    let anchor_bearing = bearing_deg(&view, anchor.center());
                    let anchor_depth = in_view(&view, anchor.center()).z;
                    for g in &same_class {
                        let (bearing, depth) =
                            (bearing_deg(&view, g.center()), in_view(&view, g.center()).z);
                        let in_line = (bearing - anchor_bearing).abs() <= 25.0;
                        let holds = match e.relation {
                            Relation::Left => bearing <= anchor_bearing - 10.0,
                            Relation::Right => bearing >= anchor_bearing + 10.0,
                            Relation::Front => in_line && depth <= anchor_depth - 0.3,
                            _ => in_line && depth >= anchor_depth + 0.3,
                        };
                        assert_eq!(holds, e.targets.contains(&g.id), "{}", e.text);
                    }
                }
                Relation::Between => {
                    let (a, b) = (
                        geometry(&scene, e.anchors[0]),
                        geometry(&scene, e.anchors[1]),
                    );
                    for g in &same_class {
                        assert_eq!(
                            is_between(g, &a, &b),
                            e.targets.contains(&g.id),
                            "{}",
                            e.text
                        );
                    }
                }
                Relation::Tallest | Relation::Highest | Relation::Lowest => {
                    let key = |g: &Geometry| match e.relation {
                        Relation::Tallest => g.hi.z - g.lo.z,
                        Relation::Highest => g.hi.z,
                        _ => -g.lo.z,
                    };
                    for g in same_class.iter().filter(|g| g.id != targets[0].id) {
                        assert!(key(&targets[0]) >= key(g) + 0.06 - 1e-9, "{}", e.text);
                    }
                }
                Relation::Leftmost | Relation::Rightmost => {
                    let view = e.view.unwrap();
                    let sign = if e.relation == Relation::Leftmost {
                        -1.0
                    } else {
                        1.0
                    };
                    let target = sign * bearing_deg(&view, targets[0].center());
                    for g in same_class.iter().filter(|g| g.id != targets[0].id) {
                        assert!(
                            target >= sign * bearing_deg(&view, g.center()) + 10.0 - 1e-9,
                            "{}",
                            e.text
                        );
                    }
                }
            }
            if let Some(view) = e.view {
                // Decided among objects the view sees: in front of the camera.
                for g in &targets {
                    assert!(in_view(&view, g.center()).z > 0.3, "{}", e.text);
                }
            }
        }
    }
}

#[test]
fn generation_is_deterministic() {
    let file = generate(Split::Benchmark, 4).unwrap();
    assert_eq!(
        scene_expressions(&file).unwrap(),
        scene_expressions(&file).unwrap()
    );
}

#[test]
fn an_observer_s_benchmark_decides_over_what_it_saw_and_asks_for_refusals_of_the_rest() {
    use groupforward_sim::referring::observed_expressions;
    let file = generate(Split::Benchmark, 3).unwrap();
    let scene = file.build().unwrap();
    let every: Vec<u16> = scene.objects.iter().map(|o| o.instance_id).collect();
    // Everything observed: the benchmark as it was, and nothing to refuse.
    let all_seen = observed_expressions(&file, &every).unwrap();
    assert_eq!(all_seen.answerable, scene_expressions(&file).unwrap());
    assert_eq!(all_seen.every_object, all_seen.answerable);
    assert!(all_seen.refusals.is_empty());
    // One object never observed, the only one of its class: no answerable expression targets it,
    // and asking for it is a refusal test.
    let hidden = scene
        .objects
        .iter()
        .find(|o| {
            scene
                .objects
                .iter()
                .filter(|p| p.class_id == o.class_id)
                .count()
                == 1
        })
        .unwrap()
        .clone();
    let observed: Vec<u16> = every
        .iter()
        .copied()
        .filter(|id| *id != hidden.instance_id)
        .collect();
    let one_hidden = observed_expressions(&file, &observed).unwrap();
    let (answerable, refusals) = (one_hidden.answerable, one_hidden.refusals);
    assert_eq!(one_hidden.every_object, all_seen.every_object);
    assert!(answerable
        .iter()
        .all(|e| !e.targets.contains(&hidden.instance_id)));
    assert!(!refusals.is_empty());
    assert!(refusals
        .iter()
        .all(|e| e.targets.iter().all(|t| *t == hidden.instance_id)));
    let texts: Vec<&str> = answerable.iter().map(|e| e.text.as_str()).collect();
    assert!(refusals.iter().all(|e| !texts.contains(&e.text.as_str())));
}

#[test]
fn a_function_some_observed_object_serves_is_no_refusal_test() {
    use groupforward_sim::referring::observed_expressions;
    // Hide one of several objects of a class: "all the things you can X" over every object then
    // names an observed object too, and asking it is answerable, not a refusal.
    for index in 0..10 {
        let file = generate(Split::Benchmark, index).unwrap();
        let scene = file.build().unwrap();
        let Some(hidden) = scene.objects.iter().find(|o| {
            scene
                .objects
                .iter()
                .filter(|p| p.class_id == o.class_id)
                .count()
                >= 2
        }) else {
            continue;
        };
        let observed: Vec<u16> = scene
            .objects
            .iter()
            .map(|o| o.instance_id)
            .filter(|id| *id != hidden.instance_id)
            .collect();
        let benchmark = observed_expressions(&file, &observed).unwrap();
        for e in &benchmark.refusals {
            assert!(
                e.targets.iter().all(|t| !observed.contains(t)),
                "{index}: {} names an observed object",
                e.text
            );
        }
        assert!(benchmark.every_object.iter().any(|e| {
            e.relation == Relation::Function
                && e.targets.contains(&hidden.instance_id)
                && e.targets.len() > 1
        }));
        return;
    }
    panic!("no benchmark scene with two objects of a class");
}
