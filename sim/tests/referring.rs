#![allow(clippy::unwrap_used)]
//! Generated referring expressions: every relation type occurs, and each expression means exactly
//! its targets, re-checked against ground truth the generator does not use (placement support,
//! plain distances and sizes).

use std::collections::BTreeMap;

use groupforward_sim::procedural::{generate, Split};
use groupforward_sim::referring::{color_name, scene_expressions, Expression, Geometry, Relation};
use groupforward_sim::render::Scene;

fn benchmark(count: u64) -> Vec<(Scene, Vec<Expression>)> {
    (0..count)
        .map(|i| {
            let file = generate(Split::Benchmark, i).unwrap();
            (file.build().unwrap(), scene_expressions(&file).unwrap())
        })
        .collect()
}

fn geometry(scene: &Scene, id: u16) -> Geometry {
    Geometry::new(scene.objects.iter().find(|o| o.instance_id == id).unwrap())
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
                .map(Geometry::new)
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
                    for g in scene.objects.iter().map(Geometry::new) {
                        let can = classes
                            .iter()
                            .any(|c| c.name == g.class && c.affordances.contains(&affordance));
                        assert_eq!(can, e.targets.contains(&g.id), "{}", e.text);
                    }
                }
                _ => {}
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
