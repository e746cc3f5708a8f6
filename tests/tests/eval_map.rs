#![allow(clippy::unwrap_used)]
//! The map the node builds, scored against ground truth end to end (`groupforward eval map`'s
//! path): the demo scene recorded, replayed through ingest, keyframes, the shipped models and
//! fusion, then matched to the scene's objects. Floors are the measured figures less a margin, so
//! a change that breaks the map (boxes, structure, duplicates, identity) fails here; then the
//! scene's referring expressions are asked on that map through the `Refer` handler.

use std::path::Path;

use groupforward::config::Config;
use groupforward::graph::persist;
use groupforward::model::ModelsSection;
use groupforward::window::WindowModels;
use groupforward_harness::eval::refer::{ask_scene, held_out_views, Referrer, SceneTruth, Truth};
use groupforward_harness::eval::run::run_scene;
use groupforward_harness::eval::score::{score_map, score_windows, Outcome};
use groupforward_sim::scene::SceneFile;

#[test]
fn the_demo_scene_s_map_finds_its_objects_and_answers_its_referring_expressions() {
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models");
    let config = Config {
        models: ModelsSection::shipped_in(&models),
        ..Config::default()
    };
    let mut window_models = WindowModels::load(&config.models, &config.semantics).unwrap();
    let scene = SceneFile::builtin("two_chairs").unwrap();
    let mut run = run_scene(&scene, &config, &mut window_models).unwrap();
    assert!(run.windows.len() >= 5, "{} windows", run.windows.len());
    // Deterministic: the same bag through the same stages builds the same map, to the bit.
    let again = run_scene(&scene, &config, &mut window_models).unwrap();
    assert_eq!(
        persist::content_hash(&run.map),
        persist::content_hash(&again.map),
        "two replays of one bag built different maps"
    );
    assert_eq!(run.instances, again.instances);
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
    // Measured: all 5 objects found (4 at IoU ≥ 0.5; the lamp at 0.49, named "box"), 5
    // instances listed (a small piece of the wall corner, named unsurely, is not); no room;
    // chair names right.
    assert_eq!(s.room_instances, 0, "the room is structure, not an object");
    assert!(s.recall_at_25 >= 0.8, "recall@0.25 {}", s.recall_at_25);
    assert_eq!(s.merged_objects, 0, "no instance stands for two objects");
    assert!(s.precision >= 0.9, "precision {}", s.precision);
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
    // Identity along the orbit: measured 14.3 switches per 100 sightings (28.6 before window
    // instances left over by the one-to-one matching could join the object they lie on: a
    // table's leg and its top competed for the table's id, and the loser was born anew).
    let switches = windows.summary().id_switches_per_100_sightings;
    assert!(
        switches <= 20.0,
        "{switches} identity switches per 100 sightings"
    );
    // Identity as a user of the map meets it, fed by the models (not by ground truth): after
    // every window, each object found in the map is found under the id it had before, and no
    // id ever stood for two objects. Measured: 0 and 0 over 49 sightings on a CPU with AVX-512
    // (a chair's id came to stand for the table when fusion folded features alike but named
    // apart); 0 shared and 1 change over 48 on an AVX2-only CPU, whose ONNX Runtime kernels
    // round differently, so the models' outputs and the map differ in their last bits.
    let map_identity = windows.summary();
    assert!(windows.map_sightings > 30, "{}", windows.map_sightings);
    assert_eq!(
        map_identity.map_ids_shared, 0,
        "an id stood for two objects"
    );
    assert!(
        windows.map_id_changes <= 1,
        "an object was found under another id than before {} times",
        windows.map_id_changes
    );

    // Referring on the same map, through the `Refer` service's handler (CDR in and out) with the
    // scene's generated expressions; answers matched to objects by their boxes. Measured: 15 of
    // 21 right, all 21 with their targets in the map. The lamp is in the map but named "box":
    // "the lamp", "give light" and the two chairs related to the lamp find no lamp, and "put
    // things on" picks the lamp; "the thing you can eat at" picks a chair. (17 were right while
    // a wall-corner piece was listed: "the lamp" picked it, and "the chair closest to the lamp"
    // came out right by its place.)
    let map = std::mem::take(&mut run.map);
    let sim = groupforward_sim::simulation::Simulation::new(scene.clone()).unwrap();
    let views = held_out_views(&sim, &map, true);
    let referrer = Referrer {
        vocabulary: window_models.vocabulary.clone(),
        encoder: window_models
            .text_encoder
            .take()
            .map(|e| std::sync::Arc::new(std::sync::Mutex::new(e))),
        section: config.refer.clone(),
    };
    let expressions: Vec<_> = groupforward_sim::referring::scene_expressions(&scene)
        .unwrap()
        .into_iter()
        .map(|e| (e, Truth::EveryObject))
        .collect();
    let truth = SceneTruth {
        objects: &run.objects,
        views: &views,
    };
    let records = ask_scene(&scene.name, referrer.shared(map), truth, &expressions);
    assert_eq!(records.len(), expressions.len());
    for r in &records {
        println!(
            "{:<40} {:?} -> {:?} {} {}",
            r.expression, r.targets, r.answered, r.correct, r.message
        );
        assert!(r.success || !r.message.is_empty(), "{}", r.expression);
        assert!(r.mask_iou.is_none_or(|v| (0.0..=1.0).contains(&v)));
    }
    let right = records.iter().filter(|r| r.correct).count();
    let in_map: Vec<_> = records.iter().filter(|r| r.targets_in_map).collect();
    let right_in_map = in_map.iter().filter(|r| r.correct).count();
    assert!(
        right * 10 >= records.len() * 7,
        "{right} of {} right",
        records.len()
    );
    assert!(
        right_in_map * 10 >= in_map.len() * 7,
        "{right_in_map} of {} in the map right",
        in_map.len()
    );
    // Right answers' masks overlap the objects in views the map was not built from.
    let right_masks: Vec<f64> = records
        .iter()
        .filter(|r| r.correct)
        .filter_map(|r| r.mask_iou)
        .collect();
    assert!(right_masks.iter().sum::<f64>() / right_masks.len() as f64 > 0.2);
}

/// A user's vocabulary of classes the simulator has never heard of, from a vocabulary file of
/// their own without priors: the text encoder names the instances with its phrases, and the map
/// runs with class-agnostic rules (no per-name prior is needed).
#[test]
fn a_vocabulary_of_classes_the_sim_never_heard_of_names_instances_without_priors() {
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models");
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("vocabulary.yaml");
    std::fs::write(
        &file,
        "classes:\n  - name: whiteboard\n  - name: fire extinguisher\n  - name: coat rack\n",
    )
    .unwrap();
    let mut config = Config {
        models: ModelsSection::shipped_in(&models),
        ..Config::default()
    };
    config.semantics.vocabulary = ["whiteboard", "fire extinguisher", "coat rack", "other"]
        .map(String::from)
        .to_vec();
    config.semantics.vocabulary_file = Some(file);
    config.validate().unwrap();
    let mut window_models = WindowModels::load(&config.models, &config.semantics).unwrap();
    let priors = &window_models.vocabulary.as_ref().unwrap().priors;
    for name in ["whiteboard", "fire extinguisher", "coat rack", "chair"] {
        assert_eq!(priors.typical_depth(name), None);
        assert_eq!(priors.largest_side(name), None);
        assert!(!priors.stands_on_floor(name));
    }
    let scene = SceneFile::builtin("two_chairs").unwrap();
    let run = run_scene(&scene, &config, &mut window_models).unwrap();
    assert!(run.windows.len() >= 5, "{} windows", run.windows.len());
    assert!(!run.map.instances.is_empty());
    assert!(!run.instances.is_empty(), "nothing listed");
    for listed in &run.instances {
        assert!(
            ["whiteboard", "fire extinguisher", "coat rack"].contains(&listed.name.as_str()),
            "{listed:?}"
        );
        assert!(listed.bbox.centre.is_finite() && listed.bbox.size.is_finite());
    }
}

/// A vocabulary file with a mistake is refused when the config is checked, naming the file, the
/// line and the class, before any model loads.
#[test]
fn a_vocabulary_file_with_a_mistake_is_a_config_error_naming_where() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("vocabulary.yaml");
    std::fs::write(&file, "classes:\n  - name: crate\n    typical_depth: 0.4\n").unwrap();
    let mut config = Config::default();
    config.semantics.vocabulary_file = Some(file.clone());
    let message = config.validate().unwrap_err().to_string();
    assert!(
        message.contains("semantics.vocabulary_file")
            && message.contains(&file.display().to_string())
            && message.contains("line 3"),
        "{message}"
    );
    config.semantics.vocabulary_file = Some(dir.path().join("missing.yaml"));
    let message = config.validate().unwrap_err().to_string();
    assert!(message.contains("missing.yaml"), "{message}");
}
