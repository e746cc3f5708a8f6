#![allow(clippy::unwrap_used)]
//! The map the node builds, scored against ground truth end to end (`groupforward eval map`'s
//! path): the demo scene recorded, replayed through ingest, keyframes, the shipped models and
//! fusion, then matched to the scene's objects. Floors are the measured figures less a margin, so
//! a change that breaks the map (boxes, structure, duplicates, identity) fails here.

use std::path::Path;

use groupforward::config::Config;
use groupforward::eval::run::run_scene;
use groupforward::eval::score::{score_map, score_windows, Outcome};
use groupforward::model::ModelsSection;
use groupforward::window::WindowModels;
use groupforward_sim::scene::SceneFile;

#[test]
fn the_demo_scene_s_map_finds_its_objects_without_the_room_or_duplicates() {
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models");
    let config = Config {
        models: ModelsSection::shipped_in(&models),
        ..Config::default()
    };
    let mut window_models = WindowModels::load(&config.models, &config.semantics).unwrap();
    let scene = SceneFile::builtin("two_chairs").unwrap();
    let run = run_scene(&scene, &config, &mut window_models).unwrap();
    assert!(run.windows.len() >= 5, "{} windows", run.windows.len());
    let (rows, counts) = score_map(
        &run.scene,
        &run.objects,
        &run.instances,
        run.room_area,
        1000,
    );
    let windows = score_windows(&run.objects, &run.windows, 200);
    for row in &rows {
        println!(
            "#{} {:<10} {:?} {} IoU {:.2} named {:?}",
            row.object, row.class, row.outcome, row.instance, row.iou, row.name
        );
    }
    let s = counts.summary();
    println!("{s:?}; windows: {:?}", windows.summary());
    // Measured: 4 objects found of 5 (the lamp, 2,073 pixels over the orbit, is missed), 4
    // instances listed, all of them objects; no room; chair names right.
    assert_eq!(s.room_instances, 0, "the room is structure, not an object");
    assert!(s.recall_at_25 >= 0.6, "recall@0.25 {}", s.recall_at_25);
    assert!(s.precision >= 0.75, "precision {}", s.precision);
    assert!(s.duplicate_rate <= 0.2, "duplicates {}", s.duplicate_rate);
    assert!(s.name_top1 >= 0.66, "names {}", s.name_top1);
    for row in rows.iter().filter(|r| r.outcome == Outcome::Found) {
        assert!(row.centre_error_m < 0.25, "{row:?}");
    }
    // Both chairs are the same class and colour: whichever is found is found at its own place.
    let found_chairs = rows
        .iter()
        .filter(|r| r.class == "chair" && r.outcome == Outcome::Found)
        .count();
    assert!(found_chairs >= 1);
    assert!(windows.sightings > 10);
}
