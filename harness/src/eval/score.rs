//! Scoring a map against ground truth (DESIGN §5.6, §7): instances matched one-to-one to objects
//! by the 3D IoU of their boxes (Kuhn–Munkres on IoU), then ScanRefer's yardstick (recall at IoU
//! 0.25 / 0.5), precision, duplicates, merged objects, names, box errors, instances that are the
//! room, and identity switches along the trajectory. Pure functions over plain boxes: the tests
//! score hand-built maps.

use std::collections::HashMap;

use pathfinding::prelude::{kuhn_munkres, Matrix};
use serde::{Deserialize, Serialize};

use groupforward::recon::boxes::OrientedBox;
use groupforward::recon::metrics::ObjectCoverage;

/// IoU thresholds of the recall figures (ScanRefer's Acc@0.25 / Acc@0.5).
pub const IOU_LOOSE: f64 = 0.25;
pub const IOU_TIGHT: f64 = 0.5;
/// An unmatched instance overlapping a matched object's box by at least this IoU is a duplicate.
pub const DUPLICATE_IOU: f64 = 0.1;
/// An instance whose footprint covers this share of the room's floor is the room.
pub const ROOM_SHARE: f64 = 0.4;

/// A ground-truth object.
#[derive(Debug, Clone, PartialEq)]
pub struct TruthObject {
    pub id: u16,
    pub class: String,
    pub bbox: OrientedBox,
    /// Pixels of it over the whole trajectory (all views); objects seen less are not scored.
    pub pixels: u64,
}

/// An instance as the map lists it.
#[derive(Debug, Clone, PartialEq)]
pub struct ListedInstance {
    pub id: String,
    /// Best name ("" when unnamed) and its score.
    pub name: String,
    pub name_score: f64,
    /// Windows it was matched in, and its Gaussians.
    pub observations: u32,
    pub gaussians: usize,
    pub bbox: OrientedBox,
}

/// What one listed instance is, against ground truth.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum InstanceOutcome {
    /// Matched one-to-one to an object at IoU ≥ 0.25.
    Object,
    /// Unmatched, but overlapping a found object at IoU ≥ the duplicate threshold.
    Duplicate,
    /// Neither: a false positive (a piece of the room, of an object, or nothing).
    Unmatched,
}

/// One listed instance's row of `instances.csv`: where the false positives are.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct InstanceRow {
    pub scene: String,
    pub instance: String,
    pub name: String,
    pub name_score: f64,
    pub observations: u32,
    pub gaussians: usize,
    /// Its box's centre (world frame) and size.
    pub centre: [f64; 3],
    pub size: [f64; 3],
    pub outcome: InstanceOutcome,
    /// The object it was matched to (or overlaps most, for duplicates and unmatched ones; 0
    /// when none) and that IoU.
    pub object: u16,
    pub object_class: String,
    pub iou: f64,
}

/// One window: the objects its views saw (id, pixels), its instances before fusion with the
/// persistent id fusion gave each, and the map's object list after the window's fusion (what a
/// user holding an id sees).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct WindowRecord {
    pub objects: Vec<(u16, u64)>,
    /// Where each object's pixels went among the window's instances (the window's own
    /// segmentation, before boxes: a partial view makes a partial box, not a bad grouping).
    pub coverage: Vec<ObjectCoverage>,
    /// Per object, its model pixels in no instance by the stage that dropped them (in the order
    /// of [`groupforward::window::Unassigned::ALL`]).
    pub unassigned: Vec<(u16, [u64; UNASSIGNED_REASONS])>,
    pub instances: Vec<(OrientedBox, String)>,
    pub map: Vec<ListedInstance>,
}

/// What became of one object.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Matched at IoU ≥ 0.25.
    Found,
    /// Inside the box of an instance matched to another object.
    Merged,
    /// No instance covers it.
    Missed,
    /// Seen by fewer pixels than scored objects need.
    NotSeen,
}

/// One object's row of the per-object table.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ObjectRow {
    pub scene: String,
    pub object: u16,
    pub class: String,
    pub pixels: u64,
    pub outcome: Outcome,
    pub instance: String,
    pub iou: f64,
    pub name: String,
    pub name_correct: bool,
    pub centre_error_m: f64,
    /// Instance box volume over the object's.
    pub size_ratio: f64,
    /// Its trail through the run ([`trace_objects`]), and where a scored object that was not
    /// found was lost.
    pub trace: ObjectTrace,
    pub lost_at: Option<LostAt>,
}

/// One object's trail through a run. Per window whose views saw it: whether a window instance's
/// box found it (IoU ≥ 0.25; a window seeing part of an object makes a partial box, so this
/// misses some good groupings), the best pixel IoU of a window instance with its pixels (the
/// segmentation itself), and where its pixels went (shares over all its sighted pixels: in that
/// best instance, in other object instances, in instances of the room, in none, and how much of
/// the best instance was something else). Then the best IoU the map had with it after any window
/// (one-to-one, as everywhere).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct ObjectTrace {
    pub window_sightings: u32,
    pub window_found: u32,
    pub window_best_iou: f64,
    pub pixel_best_iou: f64,
    pub in_best: f64,
    pub split: f64,
    pub to_structure: f64,
    pub unassigned: f64,
    pub impurity: f64,
    /// `unassigned` by the stage that dropped the pixels ([`groupforward::window::Unassigned::ALL`]'s
    /// order: not lifted, HDBSCAN noise, depth edge, speck, support, another object's class).
    pub unassigned_by: [f64; UNASSIGNED_REASONS],
    pub map_best_iou: f64,
}

/// The stages that can leave a pixel in no window instance ([`groupforward::window::Unassigned`]).
pub const UNASSIGNED_REASONS: usize = groupforward::window::Unassigned::ALL.len();

/// A window instance that covers an object's pixels at this IoU or more grouped it as itself.
pub const PIXEL_FOUND_IOU: f64 = 0.5;

/// The stage where an object not found at the end was lost: the map held it once and lost it
/// (a later fold, merge or box growth); a window grouped it as itself but the map never held it
/// (fusion, cleaning, listing, box fitting); or no window grouped it (the model, lifting or
/// HDBSCAN: its pixels given to the room, to other objects, split or left unassigned).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LostAt {
    Window,
    Fusion,
    Later,
}

impl ObjectTrace {
    /// Where this object was lost, for a scored object not found at the end.
    pub fn lost_at(&self) -> LostAt {
        if self.map_best_iou >= IOU_LOOSE {
            LostAt::Later
        } else if self.pixel_best_iou >= PIXEL_FOUND_IOU {
            LostAt::Fusion
        } else {
            LostAt::Window
        }
    }
}

/// Counts that add up over scenes; [`Counts::summary`] turns them into rates.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Counts {
    pub objects_scored: u64,
    pub objects_not_seen: u64,
    pub found_25: u64,
    pub found_50: u64,
    pub instances_listed: u64,
    /// Listed instances matched at IoU ≥ 0.25 to a scored object, or to an object seen too
    /// little to be scored (neither for nor against precision).
    pub instances_true: u64,
    pub instances_unscored: u64,
    pub duplicates: u64,
    pub merged_objects: u64,
    pub room_instances: u64,
    pub names_correct: u64,
    pub centre_error_sum_m: f64,
    pub size_ratio_log_sum: f64,
    /// IoU of each scored object with the instance matched to it (0 when none), summed.
    pub iou_sum: f64,
    /// Window level (before fusion).
    pub window_objects: u64,
    pub window_found_25: u64,
    pub window_instances: u64,
    pub window_instances_true: u64,
    pub sightings: u64,
    pub id_switches: u64,
    /// Map level, after each window: objects found in the map (IoU ≥ 0.25, one-to-one), the
    /// times an object was found under another id than the last time, and the ids that stood
    /// for more than one object over the trajectory.
    pub map_sightings: u64,
    pub map_id_changes: u64,
    pub map_ids_shared: u64,
    /// Scored objects not found at the end, by the stage that lost them ([`LostAt`]); absent
    /// from runs recorded before they were counted.
    #[serde(default)]
    pub lost_in_windows: u64,
    #[serde(default)]
    pub lost_in_fusion: u64,
    #[serde(default)]
    pub lost_later: u64,
}

impl Counts {
    pub fn add(&mut self, o: &Counts) {
        self.objects_scored += o.objects_scored;
        self.objects_not_seen += o.objects_not_seen;
        self.found_25 += o.found_25;
        self.found_50 += o.found_50;
        self.instances_listed += o.instances_listed;
        self.instances_true += o.instances_true;
        self.instances_unscored += o.instances_unscored;
        self.duplicates += o.duplicates;
        self.merged_objects += o.merged_objects;
        self.room_instances += o.room_instances;
        self.names_correct += o.names_correct;
        self.centre_error_sum_m += o.centre_error_sum_m;
        self.size_ratio_log_sum += o.size_ratio_log_sum;
        self.iou_sum += o.iou_sum;
        self.window_objects += o.window_objects;
        self.window_found_25 += o.window_found_25;
        self.window_instances += o.window_instances;
        self.window_instances_true += o.window_instances_true;
        self.sightings += o.sightings;
        self.id_switches += o.id_switches;
        self.map_sightings += o.map_sightings;
        self.map_id_changes += o.map_id_changes;
        self.map_ids_shared += o.map_ids_shared;
        self.lost_in_windows += o.lost_in_windows;
        self.lost_in_fusion += o.lost_in_fusion;
        self.lost_later += o.lost_later;
    }

    /// Count the stage each of `rows`' lost objects was lost at.
    pub fn count_losses(&mut self, rows: &[ObjectRow]) {
        for lost in rows.iter().filter_map(|r| r.lost_at) {
            match lost {
                LostAt::Window => self.lost_in_windows += 1,
                LostAt::Fusion => self.lost_in_fusion += 1,
                LostAt::Later => self.lost_later += 1,
            }
        }
    }

    pub fn summary(&self) -> Summary {
        let ratio = |a: f64, b: u64| if b == 0 { 0.0 } else { a / b as f64 };
        Summary {
            recall_at_25: ratio(self.found_25 as f64, self.objects_scored),
            recall_at_50: ratio(self.found_50 as f64, self.objects_scored),
            precision: ratio(
                self.instances_true as f64,
                self.instances_listed - self.instances_unscored,
            ),
            duplicate_rate: ratio(self.duplicates as f64, self.objects_scored),
            merged_objects: self.merged_objects,
            name_top1: ratio(self.names_correct as f64, self.found_25),
            room_instances: self.room_instances,
            id_switches_per_100_sightings: 100.0 * ratio(self.id_switches as f64, self.sightings),
            map_id_changes_per_100_sightings: 100.0
                * ratio(self.map_id_changes as f64, self.map_sightings),
            map_ids_shared: self.map_ids_shared,
            mean_centre_error_m: ratio(self.centre_error_sum_m, self.found_25),
            size_ratio_geomean: ratio(self.size_ratio_log_sum, self.found_25).exp(),
            mean_iou: ratio(self.iou_sum, self.objects_scored),
            objects_scored: self.objects_scored,
            objects_not_seen: self.objects_not_seen,
            instances_listed: self.instances_listed,
            window_recall_at_25: ratio(self.window_found_25 as f64, self.window_objects),
            window_precision: ratio(self.window_instances_true as f64, self.window_instances),
            lost_in_windows: self.lost_in_windows,
            lost_in_fusion: self.lost_in_fusion,
            lost_later: self.lost_later,
        }
    }
}

/// The map's figures (`summary.json`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Summary {
    pub recall_at_25: f64,
    pub recall_at_50: f64,
    pub precision: f64,
    pub duplicate_rate: f64,
    pub merged_objects: u64,
    pub name_top1: f64,
    pub room_instances: u64,
    pub id_switches_per_100_sightings: f64,
    /// The same over the map after each window: an object found under another persistent id
    /// than the last time it was found (a fold of its instance into an older one counts: the id
    /// a user held is gone).
    pub map_id_changes_per_100_sightings: f64,
    /// Persistent ids that stood for two or more objects over the trajectory.
    pub map_ids_shared: u64,
    pub mean_centre_error_m: f64,
    /// Geometric mean of instance over object box volume, over found objects (1 = right size).
    pub size_ratio_geomean: f64,
    /// Mean over scored objects of the IoU with the instance matched to them (0 when none): a
    /// smoother yardstick of box quality than the two recall thresholds.
    pub mean_iou: f64,
    pub objects_scored: u64,
    pub objects_not_seen: u64,
    pub instances_listed: u64,
    /// The same yardstick on the window instances before fusion (objects the window saw).
    pub window_recall_at_25: f64,
    pub window_precision: f64,
    /// Scored objects not found, by the stage that lost them ([`LostAt`]).
    pub lost_in_windows: u64,
    pub lost_in_fusion: u64,
    pub lost_later: u64,
}

/// One-to-one matching maximising total IoU; returns per row the column it got and the IoU
/// (pairs without overlap are never matched).
pub fn match_by_iou(rows: &[OrientedBox], columns: &[OrientedBox]) -> Vec<Option<(usize, f64)>> {
    if rows.is_empty() || columns.is_empty() {
        return vec![None; rows.len()];
    }
    let iou: Vec<Vec<f64>> = rows
        .iter()
        .map(|r| columns.iter().map(|c| r.iou(c)).collect())
        .collect();
    // Kuhn–Munkres needs rows ≤ columns: transpose when there are more rows.
    let transpose = rows.len() > columns.len();
    let (n, m) = if transpose {
        (columns.len(), rows.len())
    } else {
        (rows.len(), columns.len())
    };
    let scale = 1e6;
    let weights = Matrix::from_fn(n, m, |(i, j)| {
        let v = if transpose { iou[j][i] } else { iou[i][j] };
        (v * scale).round() as i64
    });
    let (_, assignment) = kuhn_munkres(&weights);
    let mut out = vec![None; rows.len()];
    for (i, &j) in assignment.iter().enumerate() {
        let (row, column) = if transpose { (j, i) } else { (i, j) };
        let value = iou[row][column];
        if value > 0.0 {
            out[row] = Some((column, value));
        }
    }
    out
}

/// Score the final map of one scene. `room_area`: the room's floor area (m²); `min_pixels`: the
/// pixels an object needs over the trajectory to be scored.
pub fn score_map(
    scene: &str,
    objects: &[TruthObject],
    instances: &[ListedInstance],
    room_area: f64,
    min_pixels: u64,
) -> (Vec<ObjectRow>, Counts) {
    let mut counts = Counts {
        instances_listed: instances.len() as u64,
        ..Counts::default()
    };
    let object_boxes: Vec<OrientedBox> = objects.iter().map(|o| o.bbox).collect();
    let instance_boxes: Vec<OrientedBox> = instances.iter().map(|i| i.bbox).collect();
    let matches = match_by_iou(&object_boxes, &instance_boxes);
    let scored = |o: &TruthObject| o.pixels >= min_pixels;
    // Instances that found an object at the loose threshold, and which object.
    let mut instance_object: HashMap<usize, usize> = HashMap::new();
    for (k, m) in matches.iter().enumerate() {
        if let Some((i, iou)) = m {
            if *iou >= IOU_LOOSE {
                instance_object.insert(*i, k);
            }
        }
    }
    for &k in instance_object.values() {
        if scored(&objects[k]) {
            counts.instances_true += 1;
        } else {
            counts.instances_unscored += 1;
        }
    }
    counts.room_instances = instances
        .iter()
        .filter(|i| room_area > 0.0 && i.bbox.footprint_area() >= ROOM_SHARE * room_area)
        .count() as u64;
    let mut rows = Vec::with_capacity(objects.len());
    for (k, object) in objects.iter().enumerate() {
        let mut row = ObjectRow {
            scene: scene.to_owned(),
            object: object.id,
            class: object.class.clone(),
            pixels: object.pixels,
            outcome: Outcome::Missed,
            instance: String::new(),
            iou: 0.0,
            name: String::new(),
            name_correct: false,
            centre_error_m: f64::NAN,
            size_ratio: f64::NAN,
            trace: ObjectTrace::default(),
            lost_at: None,
        };
        if let Some((i, iou)) = matches[k] {
            let instance = &instances[i];
            row.instance = instance.id.clone();
            row.iou = iou;
            row.name = instance.name.clone();
            row.name_correct = instance.name == object.class;
            row.centre_error_m = (instance.bbox.centre - object.bbox.centre).length();
            row.size_ratio = instance.bbox.volume() / object.bbox.volume().max(1e-9);
        }
        if !scored(object) {
            row.outcome = Outcome::NotSeen;
            counts.objects_not_seen += 1;
            rows.push(row);
            continue;
        }
        counts.objects_scored += 1;
        counts.iou_sum += row.iou;
        if row.iou >= IOU_LOOSE {
            row.outcome = Outcome::Found;
            counts.found_25 += 1;
            counts.found_50 += u64::from(row.iou >= IOU_TIGHT);
            counts.names_correct += u64::from(row.name_correct);
            counts.centre_error_sum_m += row.centre_error_m;
            counts.size_ratio_log_sum += row.size_ratio.max(1e-9).ln();
        } else {
            // Merged: its centre lies in the box of an instance that found another object.
            let merged = instance_object
                .iter()
                .any(|(&i, &other)| other != k && instances[i].bbox.contains(object.bbox.centre));
            if merged {
                row.outcome = Outcome::Merged;
                counts.merged_objects += 1;
            }
        }
        rows.push(row);
    }
    // Duplicates: listed instances that found nothing but overlap an object another instance found.
    let found_objects: Vec<usize> = instance_object.values().copied().collect();
    counts.duplicates = instances
        .iter()
        .enumerate()
        .filter(|(i, _)| !instance_object.contains_key(i))
        .filter(|(_, instance)| {
            found_objects
                .iter()
                .any(|&k| instance.bbox.iou(&objects[k].bbox) >= DUPLICATE_IOU)
        })
        .count() as u64;
    (rows, counts)
}

/// Each listed instance of one scene's final map against the objects (the same one-to-one
/// matching as [`score_map`]).
pub fn score_instances(
    scene: &str,
    objects: &[TruthObject],
    instances: &[ListedInstance],
) -> Vec<InstanceRow> {
    let object_boxes: Vec<OrientedBox> = objects.iter().map(|o| o.bbox).collect();
    let instance_boxes: Vec<OrientedBox> = instances.iter().map(|i| i.bbox).collect();
    // Objects as rows, as in `score_map`, so both see the same matching.
    let mut matched: Vec<Option<(usize, f64)>> = vec![None; instances.len()];
    for (k, m) in match_by_iou(&object_boxes, &instance_boxes)
        .iter()
        .enumerate()
    {
        if let Some((i, iou)) = m {
            if *iou >= IOU_LOOSE {
                matched[*i] = Some((k, *iou));
            }
        }
    }
    let found: Vec<usize> = matched.iter().flatten().map(|(k, _)| *k).collect();
    instances
        .iter()
        .zip(&matched)
        .map(|(instance, m)| {
            let (outcome, object, iou) = match m {
                Some((k, iou)) => (InstanceOutcome::Object, Some(*k), *iou),
                None => {
                    let overlap = |k: usize| instance.bbox.iou(&objects[k].bbox);
                    let nearest = (0..objects.len())
                        .map(|k| (k, overlap(k)))
                        .filter(|(_, iou)| *iou > 0.0)
                        .max_by(|a, b| a.1.total_cmp(&b.1));
                    let outcome = if found.iter().any(|&k| overlap(k) >= DUPLICATE_IOU) {
                        InstanceOutcome::Duplicate
                    } else {
                        InstanceOutcome::Unmatched
                    };
                    (outcome, nearest.map(|n| n.0), nearest.map_or(0.0, |n| n.1))
                }
            };
            InstanceRow {
                scene: scene.to_owned(),
                instance: instance.id.clone(),
                name: instance.name.clone(),
                name_score: instance.name_score,
                observations: instance.observations,
                gaussians: instance.gaussians,
                centre: instance.bbox.centre.to_array(),
                size: instance.bbox.size.to_array(),
                outcome,
                object: object.map_or(0, |k| objects[k].id),
                object_class: object.map_or(String::new(), |k| objects[k].class.clone()),
                iou,
            }
        })
        .collect()
}

/// Score the windows of one scene: each window's instances against the objects it saw (at least
/// `min_pixels` in the window's views), and the persistent id every sighting got. An identity
/// switch is an object sighted under another id than at its previous sighting. Then the map
/// after each window against the objects seen so far (at least `min_pixels` in all windows up
/// to it): which id each object is found under, and which ids stood for two objects.
pub fn score_windows(objects: &[TruthObject], windows: &[WindowRecord], min_pixels: u64) -> Counts {
    let mut counts = Counts::default();
    let mut last_id: HashMap<u16, String> = HashMap::new();
    let mut seen_so_far: HashMap<u16, u64> = HashMap::new();
    let mut last_map_id: HashMap<u16, String> = HashMap::new();
    let mut id_objects: HashMap<String, std::collections::BTreeSet<u16>> = HashMap::new();
    for window in windows {
        for (id, pixels) in &window.objects {
            *seen_so_far.entry(*id).or_default() += pixels;
        }
        let known: Vec<&TruthObject> = objects
            .iter()
            .filter(|o| seen_so_far.get(&o.id).is_some_and(|&p| p >= min_pixels))
            .collect();
        let known_boxes: Vec<OrientedBox> = known.iter().map(|o| o.bbox).collect();
        let map_boxes: Vec<OrientedBox> = window.map.iter().map(|i| i.bbox).collect();
        for (object, m) in known.iter().zip(match_by_iou(&known_boxes, &map_boxes)) {
            let Some((i, iou)) = m else { continue };
            if iou < IOU_LOOSE {
                continue;
            }
            let id = &window.map[i].id;
            counts.map_sightings += 1;
            id_objects.entry(id.clone()).or_default().insert(object.id);
            if let Some(previous) = last_map_id.insert(object.id, id.clone()) {
                counts.map_id_changes += u64::from(&previous != id);
            }
        }
    }
    counts.map_ids_shared = id_objects.values().filter(|o| o.len() > 1).count() as u64;
    for window in windows {
        let seen: Vec<&TruthObject> = window
            .objects
            .iter()
            .filter(|(_, pixels)| *pixels >= min_pixels)
            .filter_map(|(id, _)| objects.iter().find(|o| o.id == *id))
            .collect();
        let boxes: Vec<OrientedBox> = seen.iter().map(|o| o.bbox).collect();
        let instance_boxes: Vec<OrientedBox> = window.instances.iter().map(|i| i.0).collect();
        let matches = match_by_iou(&boxes, &instance_boxes);
        counts.window_objects += seen.len() as u64;
        counts.window_instances += window.instances.len() as u64;
        for (object, m) in seen.iter().zip(&matches) {
            let Some((i, iou)) = m else { continue };
            if *iou < IOU_LOOSE {
                continue;
            }
            counts.window_found_25 += 1;
            counts.window_instances_true += 1;
            counts.sightings += 1;
            let id = &window.instances[*i].1;
            if let Some(previous) = last_id.insert(object.id, id.clone()) {
                counts.id_switches += u64::from(&previous != id);
            }
        }
    }
    counts
}

/// Each object's trail through the windows of one scene ([`ObjectTrace`], in `objects`' order):
/// the window instances matched to the objects each window saw by at least `min_pixels`, as
/// [`score_windows`] matches them, and the map after each window against every object.
pub fn trace_objects(
    objects: &[TruthObject],
    windows: &[WindowRecord],
    min_pixels: u64,
) -> Vec<ObjectTrace> {
    let mut traces = vec![ObjectTrace::default(); objects.len()];
    let mut covered_pixels = vec![0.0f64; objects.len()];
    let object_boxes: Vec<OrientedBox> = objects.iter().map(|o| o.bbox).collect();
    for window in windows {
        let seen: Vec<usize> = window
            .objects
            .iter()
            .filter(|(_, pixels)| *pixels >= min_pixels)
            .filter_map(|(id, _)| objects.iter().position(|o| o.id == *id))
            .collect();
        let seen_boxes: Vec<OrientedBox> = seen.iter().map(|&k| object_boxes[k]).collect();
        let instance_boxes: Vec<OrientedBox> = window.instances.iter().map(|i| i.0).collect();
        for (&k, m) in seen.iter().zip(match_by_iou(&seen_boxes, &instance_boxes)) {
            let trace = &mut traces[k];
            trace.window_sightings += 1;
            if let Some((_, iou)) = m {
                trace.window_best_iou = trace.window_best_iou.max(iou);
                trace.window_found += u32::from(iou >= IOU_LOOSE);
            }
            let id = u32::from(objects[k].id);
            if let Some(c) = window.coverage.iter().find(|c| c.object == id) {
                let n = c.pixels as f64;
                trace.pixel_best_iou = trace.pixel_best_iou.max(c.best_iou);
                trace.in_best += n * c.in_best;
                trace.split += n * c.split;
                trace.to_structure += n * c.to_structure;
                trace.unassigned += n * c.unassigned;
                trace.impurity += n * c.impurity;
                covered_pixels[k] += n;
            }
            if let Some((_, dropped)) = window.unassigned.iter().find(|(o, _)| *o == objects[k].id)
            {
                for (sum, &n) in trace.unassigned_by.iter_mut().zip(dropped) {
                    *sum += n as f64;
                }
            }
        }
        let map_boxes: Vec<OrientedBox> = window.map.iter().map(|i| i.bbox).collect();
        for (trace, m) in traces
            .iter_mut()
            .zip(match_by_iou(&object_boxes, &map_boxes))
        {
            if let Some((_, iou)) = m {
                trace.map_best_iou = trace.map_best_iou.max(iou);
            }
        }
    }
    for (trace, &n) in traces.iter_mut().zip(&covered_pixels) {
        if n > 0.0 {
            for share in [
                &mut trace.in_best,
                &mut trace.split,
                &mut trace.to_structure,
                &mut trace.unassigned,
                &mut trace.impurity,
            ] {
                *share /= n;
            }
            for share in &mut trace.unassigned_by {
                *share /= n;
            }
        }
    }
    traces
}

/// Put each object's trace on its row, and for a scored object not found, the stage that lost it.
pub fn attach_traces(rows: &mut [ObjectRow], objects: &[TruthObject], traces: &[ObjectTrace]) {
    for row in rows {
        let Some(k) = objects.iter().position(|o| o.id == row.object) else {
            continue;
        };
        row.trace = traces[k];
        let scored = row.outcome != Outcome::NotSeen && row.outcome != Outcome::Found;
        row.lost_at = scored.then(|| row.trace.lost_at());
    }
}

#[cfg(test)]
mod tests {
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
            },
            WindowRecord {
                objects: vec![(1, 500), (4, 50)],
                coverage: vec![covered(1, 0.7, 0.0)],
                unassigned: vec![],
                instances: vec![at(0.0, 0.5, "a")],
                // The map's box for 4 grew to three times its size (IoU 1/27).
                map: vec![listed("a", 0.0, 0.5), listed("d", 6.0, 1.5)],
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
}
