//! Following objects through a scene's windows: identity switches across sightings, and per
//! object where it was lost (no window grouped it, fusion never held it, or the map lost it).

use std::collections::{BTreeMap, BTreeSet, HashMap};

use serde::Serialize;

use super::*;

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

/// One change of the map id an object is found under ([`identity_events`]): at window `window`
/// (its index in the scene), `object` was found under `id` after `previous_id`; `folded` when that
/// window folded `previous_id` into `id` (the fold rules joined two instances), not a rematch.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct IdChange {
    pub window: usize,
    pub object: u16,
    pub previous_id: String,
    pub id: String,
    pub folded: bool,
}

/// The map ids of one scene's run: per window, the map after it against the objects seen so far
/// (at least `min_pixels` in all windows up to it), matched one to one at IoU ≥ 0.25. Returns the
/// sightings (object found in the map after a window), every id change, and per map id the
/// objects it was found as (an id found as two objects stood for both).
pub fn identity_events(
    objects: &[TruthObject],
    windows: &[WindowRecord],
    min_pixels: u64,
) -> (u64, Vec<IdChange>, BTreeMap<String, BTreeSet<u16>>) {
    let mut seen_so_far: HashMap<u16, u64> = HashMap::new();
    let mut last_map_id: HashMap<u16, String> = HashMap::new();
    let mut id_objects: BTreeMap<String, BTreeSet<u16>> = BTreeMap::new();
    let (mut sightings, mut changes) = (0u64, Vec::new());
    for (k, window) in windows.iter().enumerate() {
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
            sightings += 1;
            id_objects.entry(id.clone()).or_default().insert(object.id);
            match last_map_id.insert(object.id, id.clone()) {
                Some(previous) if &previous != id => changes.push(IdChange {
                    window: k,
                    object: object.id,
                    folded: window.folds.contains(&(previous.clone(), id.clone())),
                    previous_id: previous,
                    id: id.clone(),
                }),
                _ => {}
            }
        }
    }
    (sightings, changes, id_objects)
}

/// Score the windows of one scene: each window's instances against the objects it saw (at least
/// `min_pixels` in the window's views), and the persistent id every sighting got. An identity
/// switch is an object sighted under another id than at its previous sighting. Then the map
/// after each window against the objects seen so far ([`identity_events`]): which id each object
/// is found under, and which ids stood for two objects.
pub fn score_windows(objects: &[TruthObject], windows: &[WindowRecord], min_pixels: u64) -> Counts {
    let mut counts = Counts::default();
    let mut last_id: HashMap<u16, String> = HashMap::new();
    let (sightings, changes, id_objects) = identity_events(objects, windows, min_pixels);
    counts.map_sightings = sightings;
    counts.map_id_changes = changes.len() as u64;
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
    for (w, window) in windows.iter().enumerate() {
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
            if let Some((j, iou)) = m {
                tracing::debug!(
                    window = w,
                    object = objects[k].id,
                    class = %objects[k].class,
                    window_instance = j,
                    iou = format!("{iou:.2}"),
                    to = %window.instances[j].1,
                    "object grouped by the window"
                );
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
        for ((trace, m), object) in traces
            .iter_mut()
            .zip(match_by_iou(&object_boxes, &map_boxes))
            .zip(objects)
        {
            if let Some((j, iou)) = m {
                tracing::debug!(
                    window = w,
                    object = object.id,
                    class = %object.class,
                    instance = %window.map[j].id,
                    iou = format!("{iou:.2}"),
                    "object held by the map"
                );
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
