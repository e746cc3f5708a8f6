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

mod traces;

pub use traces::{
    attach_traces, identity_events, score_windows, trace_objects, IdChange, LostAt, ObjectTrace,
    PIXEL_FOUND_IOU, UNASSIGNED_REASONS,
};

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
    /// The instances the window's fusion folded into others: (absorbed, survivor) ids.
    pub folds: Vec<(String, String)>,
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

#[cfg(test)]
mod tests;
