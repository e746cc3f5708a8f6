use glam::DVec3;

use super::*;

fn object(id: u16, x: f64, size: f64) -> TruthObject {
    TruthObject {
        id,
        class: "chair".into(),
        bbox: OrientedBox {
            centre: DVec3::new(x, 0.0, size / 2.0),
            size: DVec3::splat(size),
            yaw: 0.0,
        },
        pixels: 5_000,
    }
}

fn listed(id: &str, x: f64, size: f64) -> ListedInstance {
    ListedInstance {
        id: id.into(),
        name: "chair".into(),
        name_score: 0.9,
        observations: 3,
        gaussians: 500,
        bbox: object(0, x, size).bbox,
    }
}

fn objects() -> Vec<TruthObject> {
    vec![
        object(1, 0.0, 0.5),
        object(2, 2.0, 0.5),
        object(3, 4.0, 0.5),
    ]
}

#[test]
fn a_perfect_map_scores_perfectly() {
    let map = vec![
        listed("a", 0.0, 0.5),
        listed("b", 2.0, 0.5),
        listed("c", 4.0, 0.5),
    ];
    let (rows, counts) = score_map("s", &objects(), &map, 30.0, 1000);
    let s = counts.summary();
    assert_eq!(
        (s.recall_at_25, s.recall_at_50, s.precision),
        (1.0, 1.0, 1.0)
    );
    assert_eq!(
        (s.duplicate_rate, s.merged_objects, s.room_instances),
        (0.0, 0, 0)
    );
    assert_eq!(s.name_top1, 1.0);
    assert!(s.mean_centre_error_m < 1e-12 && (s.size_ratio_geomean - 1.0).abs() < 1e-9);
    assert!((s.mean_iou - 1.0).abs() < 1e-9);
    assert!(rows.iter().all(|r| r.outcome == Outcome::Found));
}

#[test]
fn shifted_boxes_count_at_the_loose_threshold_only() {
    // 0.2 m along x of a 0.5 m cube: IoU 0.3 / 0.7 = 0.43.
    let map = vec![
        listed("a", 0.2, 0.5),
        listed("b", 2.0, 0.5),
        listed("c", 4.0, 0.5),
    ];
    let (rows, counts) = score_map("s", &objects(), &map, 30.0, 1000);
    let s = counts.summary();
    assert!((rows[0].iou - 0.3 / 0.7).abs() < 1e-9);
    assert!((s.recall_at_25 - 1.0).abs() < 1e-12);
    assert!((s.recall_at_50 - 2.0 / 3.0).abs() < 1e-12);
    assert!((rows[0].centre_error_m - 0.2).abs() < 1e-9);
    assert!((s.mean_iou - (0.3 / 0.7 + 2.0) / 3.0).abs() < 1e-9);
}

#[test]
fn a_split_object_gives_a_duplicate_and_costs_precision() {
    // Object 1 in two halves; the bigger half is matched, the other is a duplicate.
    let map = vec![
        ListedInstance {
            bbox: OrientedBox {
                centre: DVec3::new(-0.1, 0.0, 0.25),
                size: DVec3::new(0.3, 0.5, 0.5),
                yaw: 0.0,
            },
            ..listed("a", 0.0, 0.5)
        },
        ListedInstance {
            bbox: OrientedBox {
                centre: DVec3::new(0.15, 0.0, 0.25),
                size: DVec3::new(0.2, 0.5, 0.5),
                yaw: 0.0,
            },
            ..listed("a2", 0.0, 0.5)
        },
        listed("b", 2.0, 0.5),
        listed("c", 4.0, 0.5),
    ];
    let (_, counts) = score_map("s", &objects(), &map, 30.0, 1000);
    let s = counts.summary();
    assert_eq!(s.recall_at_25, 1.0);
    assert!((s.precision - 0.75).abs() < 1e-12);
    assert!((s.duplicate_rate - 1.0 / 3.0).abs() < 1e-12);
}

#[test]
fn two_objects_in_one_instance_are_merged_and_the_room_is_counted() {
    // One instance spans objects 1 and 2; another covers the whole 6 x 5 m room.
    let map = vec![
        ListedInstance {
            bbox: OrientedBox {
                centre: DVec3::new(1.0, 0.0, 0.25),
                size: DVec3::new(2.6, 0.6, 0.5),
                yaw: 0.0,
            },
            ..listed("ab", 0.0, 0.5)
        },
        listed("c", 4.0, 0.5),
        ListedInstance {
            name: "other".into(),
            bbox: OrientedBox {
                centre: DVec3::new(3.0, 2.5, 1.5),
                size: DVec3::new(6.0, 5.0, 3.0),
                yaw: 0.0,
            },
            ..listed("room", 0.0, 0.5)
        },
    ];
    let (rows, counts) = score_map("s", &objects(), &map, 30.0, 1000);
    let s = counts.summary();
    assert_eq!(s.room_instances, 1);
    // The spanning box holds cube 1 whole: IoU 0.125 / 0.78 = 0.16, under the threshold, so
    // no object is found by it and none counts as merged into a found one.
    assert_eq!(rows[0].outcome, Outcome::Missed);
    assert!((s.recall_at_25 - 1.0 / 3.0).abs() < 1e-12);
    // A box that finds a 1 m object (IoU 1 / 2.6) and also covers a small one's centre.
    let map = vec![
        ListedInstance {
            bbox: OrientedBox {
                centre: DVec3::new(0.8, 0.0, 0.5),
                size: DVec3::new(2.6, 1.0, 1.0),
                yaw: 0.0,
            },
            ..listed("ab", 0.0, 0.5)
        },
        listed("c", 4.0, 0.5),
    ];
    let objects = vec![
        object(1, 0.0, 1.0),
        object(2, 2.0, 0.3),
        object(3, 4.0, 0.5),
    ];
    let (rows, counts) = score_map("s", &objects, &map, 30.0, 1000);
    assert_eq!(rows[0].outcome, Outcome::Found, "{rows:?}");
    assert_eq!(rows[1].outcome, Outcome::Merged, "{rows:?}");
    assert_eq!(counts.merged_objects, 1);
}

#[test]
fn an_empty_map_and_unseen_objects_score_without_nan() {
    let mut objects = objects();
    objects[2].pixels = 10;
    let (rows, counts) = score_map("s", &objects, &[], 30.0, 1000);
    let s = counts.summary();
    assert_eq!(
        (
            s.recall_at_25,
            s.precision,
            s.objects_scored,
            s.objects_not_seen
        ),
        (0.0, 0.0, 2, 1)
    );
    assert_eq!(rows[2].outcome, Outcome::NotSeen);
    let summary = serde_json::to_string(&s).unwrap();
    assert!(
        !summary.contains("NaN") && !summary.contains("null"),
        "{summary}"
    );
    let (_, none) = score_map("s", &[], &[], 30.0, 1000);
    assert_eq!(none.summary().recall_at_25, 0.0);
}

#[test]
fn identity_switches_are_counted_per_sighting() {
    let objects = objects();
    let at = |x: f64, id: &str| (object(0, x, 0.5).bbox, id.to_owned());
    let windows = vec![
        WindowRecord {
            objects: vec![(1, 500), (2, 500)],
            instances: vec![at(0.0, "a"), at(2.0, "b")],
            map: vec![],
            ..WindowRecord::default()
        },
        WindowRecord {
            objects: vec![(1, 500), (2, 500), (3, 10)],
            instances: vec![at(0.0, "a"), at(2.0, "c"), at(4.0, "d")],
            map: vec![],
            ..WindowRecord::default()
        },
        WindowRecord {
            objects: vec![(2, 500)],
            instances: vec![at(2.0, "c")],
            map: vec![],
            ..WindowRecord::default()
        },
    ];
    let counts = score_windows(&objects, &windows, 100);
    assert_eq!(counts.sightings, 5);
    assert_eq!(counts.id_switches, 1, "object 2 went from b to c once");
    // Object 3 was seen by too few pixels in its window: its instance counts against
    // window precision only.
    assert_eq!((counts.window_objects, counts.window_instances), (5, 6));
    assert_eq!(counts.window_found_25, 5);
}

#[test]
fn map_identity_counts_an_id_that_moves_to_another_object_and_an_object_that_changes_id() {
    let objects = objects();
    let window = |seen: Vec<(u16, u64)>, map: Vec<ListedInstance>| WindowRecord {
        objects: seen,
        instances: vec![],
        map,
        ..WindowRecord::default()
    };
    let windows = vec![
        // Object 3 is in the map before it was seen enough: not yet counted.
        window(
            vec![(1, 600), (2, 600), (3, 10)],
            vec![
                listed("a", 0.0, 0.5),
                listed("b", 2.0, 0.5),
                listed("z", 4.0, 0.5),
            ],
        ),
        // Object 1 is now found under "b" (the id that was object 2's): one change for
        // object 1, and "b" stands for two objects; object 2 not found this time.
        window(vec![(1, 600)], vec![listed("b", 0.0, 0.5)]),
        // Object 2 back under its own id: no change for it.
        window(vec![(2, 600)], vec![listed("b", 2.0, 0.5)]),
    ];
    let counts = score_windows(&objects, &windows, 500);
    assert_eq!(counts.map_sightings, 4);
    assert_eq!(counts.map_id_changes, 1);
    assert_eq!(counts.map_ids_shared, 1);
    let s = counts.summary();
    assert_eq!(s.map_id_changes_per_100_sightings, 25.0);
    assert_eq!(s.map_ids_shared, 1);
    // The events behind the counts: the change a rematch, until the window says it folded "a"
    // into "b".
    let change = |folded| IdChange {
        window: 1,
        object: 1,
        previous_id: "a".into(),
        id: "b".into(),
        folded,
    };
    let (sightings, changes, ids) = identity_events(&objects, &windows, 500);
    assert_eq!((sightings, changes), (4, vec![change(false)]));
    assert_eq!(ids["b"], [1, 2].into_iter().collect());
    let mut folded = windows.clone();
    folded[1].folds = vec![("a".into(), "b".into())];
    assert_eq!(
        identity_events(&objects, &folded, 500).1,
        vec![change(true)]
    );
}

#[test]
fn each_listed_instance_is_an_object_a_duplicate_or_unmatched() {
    let objects = objects();
    let map = vec![
        listed("a", 0.0, 0.5),
        // Half of object 1 again: overlaps the found object (a duplicate).
        ListedInstance {
            bbox: OrientedBox {
                centre: DVec3::new(0.1, 0.0, 0.25),
                size: DVec3::new(0.3, 0.5, 0.5),
                yaw: 0.0,
            },
            ..listed("a2", 0.0, 0.5)
        },
        // Overlaps object 3, which nothing found, too little to be it.
        listed("c", 4.4, 0.5),
        listed("far", 10.0, 0.5),
    ];
    let rows = score_instances("s", &objects, &map);
    let outcomes: Vec<_> = rows.iter().map(|r| (r.outcome, r.object)).collect();
    assert_eq!(
        outcomes,
        [
            (InstanceOutcome::Object, 1),
            (InstanceOutcome::Duplicate, 1),
            (InstanceOutcome::Unmatched, 3),
            (InstanceOutcome::Unmatched, 0),
        ]
    );
    assert!((rows[0].iou - 1.0).abs() < 1e-9);
    assert!(rows[2].iou > 0.0 && rows[2].iou < IOU_LOOSE);
    assert_eq!(rows[3].iou, 0.0);
    // The same matching as the object table.
    let (object_rows, _) = score_map("s", &objects, &map, 30.0, 1000);
    assert_eq!(object_rows[0].instance, "a");
}

#[test]
fn each_lost_object_is_traced_to_the_stage_that_lost_it() {
    // Four chairs: 1 found everywhere; 2 given to the room in its window; 3 grouped as itself
    // by its window, which saw a part of it (a small box), but never held by the map; 4
    // held by the map after the first window, its box grown past it at the end.
    let mut objects = objects();
    objects.push(object(4, 6.0, 0.5));
    let at = |x: f64, size: f64, id: &str| (object(0, x, size).bbox, id.to_owned());
    let covered = |object: u32, best_iou: f64, to_structure: f64| ObjectCoverage {
        object,
        pixels: 1000,
        best_iou,
        in_best: best_iou,
        split: 0.0,
        to_structure,
        unassigned: 1.0 - best_iou - to_structure,
        impurity: 0.0,
    };
    let windows = vec![
        WindowRecord {
            objects: vec![(1, 500), (2, 500), (3, 500), (4, 500)],
            coverage: vec![
                covered(1, 0.9, 0.0),
                covered(2, 0.1, 0.8),
                covered(3, 0.8, 0.0),
                covered(4, 0.9, 0.0),
            ],
            // Object 2's 100 pixels in no instance: 60 HDBSCAN noise, 40 on a depth edge.
            unassigned: vec![(2, [0, 60, 40, 0, 0, 0])],
            instances: vec![at(0.0, 0.5, "a"), at(4.0, 0.15, "c"), at(6.0, 0.5, "d")],
            map: vec![listed("a", 0.0, 0.5), listed("d", 6.0, 0.5)],
            folds: vec![],
        },
        WindowRecord {
            objects: vec![(1, 500), (4, 50)],
            coverage: vec![covered(1, 0.7, 0.0)],
            unassigned: vec![],
            instances: vec![at(0.0, 0.5, "a")],
            // The map's box for 4 grew to three times its size (IoU 1/27).
            map: vec![listed("a", 0.0, 0.5), listed("d", 6.0, 1.5)],
            folds: vec![],
        },
    ];
    let map = windows[1].map.clone();
    let (mut rows, mut counts) = score_map("s", &objects, &map, 30.0, 100);
    let traces = trace_objects(&objects, &windows, 100);
    attach_traces(&mut rows, &objects, &traces);
    counts.count_losses(&rows);
    let lost: Vec<Option<LostAt>> = rows.iter().map(|r| r.lost_at).collect();
    assert_eq!(
        lost,
        [
            None,
            Some(LostAt::Window),
            Some(LostAt::Fusion),
            Some(LostAt::Later)
        ]
    );
    // Object 3's box was too small to count; its pixels say the window had it.
    assert_eq!((traces[2].window_found, traces[2].pixel_best_iou), (0, 0.8));
    assert!((traces[1].to_structure - 0.8).abs() < 1e-9);
    let by_stage = traces[1].unassigned_by;
    assert!((by_stage[1] - 0.06).abs() < 1e-9 && (by_stage[2] - 0.04).abs() < 1e-9);
    // Object 4's second window saw it by too few pixels to count as a sighting.
    assert_eq!((traces[3].window_sightings, traces[3].window_found), (1, 1));
    assert!((traces[3].map_best_iou - 1.0).abs() < 1e-9);
    // Object 1's shares are averaged over its sighted pixels: (0.9 + 0.7) / 2.
    assert_eq!((traces[0].window_sightings, traces[0].window_found), (2, 2));
    assert!((traces[0].in_best - 0.8).abs() < 1e-9);
    assert_eq!(
        (
            counts.lost_in_windows,
            counts.lost_in_fusion,
            counts.lost_later
        ),
        (1, 1, 1)
    );
    let summary = counts.summary();
    assert_eq!(
        summary.lost_in_windows + summary.lost_in_fusion + summary.lost_later,
        3
    );
}
