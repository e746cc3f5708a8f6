//! Fusion: one window's instances into the persistent map, in named steps ([`SceneMap::fuse`]):
//! associate them with the persistent ones (3D overlap plus prototype similarity, Kuhn–Munkres,
//! then parts: [`associate`]), split an instance the window saw as two alike objects
//! ([`contested`]), merge each into its match or give it birth, let unmatched
//! instances where a view sees free space lose confidence and die ([`free_space`]), fold what is
//! one object ([`folds`]), and clear what lies beyond the clearing radius.

mod associate;
mod contested;
mod folds;
mod footprint;
mod free_space;
mod shapes;

use std::collections::VecDeque;

use glam::Vec3;

use super::error::GraphError;
use super::instance::{capped, FusionParams, Instance};
use crate::frame::{Keyframe, WindowInstance, WindowView};
use crate::recon::depth_noise::median_measured;
use associate::Association;
use folds::birth_order;
use free_space::{in_view, mean_camera_centre, probes_beyond, seen_free, seen_through_fraction};

pub use folds::{is_back_of, is_leg_of};

/// What fusion asks of the vocabulary about instances' prototypes. Any `Fn(&[f32], &[f32]) ->
/// bool` is one that answers only the first question.
pub trait Kinds {
    /// Whether two prototypes name one kind of object (not structure).
    fn same_kind(&self, a: &[f32], b: &[f32]) -> bool;
    /// The longest horizontal side (m) an object of `prototype`'s kind has; `None` when unknown.
    fn largest_side(&self, _prototype: &[f32]) -> Option<f64> {
        None
    }
    /// The typical longer horizontal side (m) of an object of `prototype`'s kind; `None` when
    /// unknown.
    fn typical_length(&self, _prototype: &[f32]) -> Option<f64> {
        None
    }
    /// The typical shorter horizontal side (m) of an object of `prototype`'s kind; `None` when
    /// unknown.
    fn typical_depth(&self, _prototype: &[f32]) -> Option<f64> {
        None
    }
}

impl<F: Fn(&[f32], &[f32]) -> bool> Kinds for F {
    fn same_kind(&self, a: &[f32], b: &[f32]) -> bool {
        self(a, b)
    }
}

/// What one fusion step did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FusionReport {
    /// For each window instance, the persistent id it became part of.
    pub assigned: Vec<String>,
    pub merged: usize,
    pub born: usize,
    /// Duplicates folded into an older instance: (absorbed id, surviving id).
    pub absorbed: Vec<(String, String)>,
    pub missed: usize,
    pub died: usize,
    pub cleared: usize,
}

impl FusionReport {
    /// Record folds (absorbed, survivor): window instances that went into an absorbed instance
    /// are reported under its survivor. Returns the survivors' ids.
    fn record_folds(&mut self, folded: Vec<(String, String)>) -> rustc_hash::FxHashSet<String> {
        let mut survivors = rustc_hash::FxHashSet::default();
        for (absorbed, survivor) in folded {
            tracing::debug!(%absorbed, %survivor, "fold: one object by the map's rules");
            for id in self.assigned.iter_mut().filter(|id| **id == absorbed) {
                id.clone_from(&survivor);
            }
            survivors.insert(survivor.clone());
            self.absorbed.push((absorbed, survivor));
        }
        survivors
    }
}

/// The persistent map.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SceneMap {
    pub instances: Vec<Instance>,
    pub keyframes: VecDeque<Keyframe>,
    pub next_id: u64,
    pub params: FusionParams,
    /// Pairs of instances (ids, the smaller first) that one window saw as two objects while
    /// both were already in the map ([`SceneMap::seen_apart`]).
    pub seen_apart: std::collections::BTreeSet<(String, String)>,
}

impl SceneMap {
    pub fn new(params: FusionParams) -> Self {
        Self {
            params,
            ..Self::default()
        }
    }

    fn new_id(&mut self) -> String {
        self.next_id += 1;
        format!("inst_{:06}", self.next_id)
    }

    /// Fuse one window's instances, seen from `views`, at `stamp_nanos`.
    pub fn fuse(
        &mut self,
        window: Vec<WindowInstance>,
        views: &[WindowView],
        stamp_nanos: i64,
    ) -> Result<FusionReport, GraphError> {
        self.fuse_with(window, views, stamp_nanos, &|_: &[f32], _: &[f32]| true)
    }

    /// [`SceneMap::fuse`], where map-level duplicates fold only if `kinds` says their prototypes
    /// name one kind, and an instance is split only where `kinds` knows its name's sizes.
    fn fuse_with(
        &mut self,
        window: Vec<WindowInstance>,
        views: &[WindowView],
        stamp_nanos: i64,
        kinds: &dyn Kinds,
    ) -> Result<FusionReport, GraphError> {
        let same_kind = &|a: &[f32], b: &[f32]| kinds.same_kind(a, b);
        let viewpoint = mean_camera_centre(views);
        let range_noise = range_noise_of(&window, views, viewpoint);
        validate(&window)?;
        let mut report = FusionReport::default();
        let mut window = window;
        let mut association = associate::associate(self, &window, same_kind);
        let splits = self.split_where_seen_as_two(&mut window, &mut association, kinds);
        let duplicates = association.duplicates(self, same_kind);
        let (matched, absorbed) = self.merge_or_birth(
            window,
            &association,
            &duplicates,
            Sighting {
                viewpoint,
                range_noise: &range_noise,
                stamp_nanos,
            },
            &mut report,
        );
        self.record_seen_apart(&association, &report);
        self.record_split_apart(&splits, &report);
        let mut keep: Vec<bool> = (0..self.instances.len())
            .map(|j| j >= absorbed.len() || !absorbed[j])
            .collect();
        self.lose_confidence_where_seen_through(&matched, views, &mut keep, &mut report);
        // Duplicates the association could not see (two window instances of one object born in
        // the same window, or parts that grew together): fold them, younger into older. Only
        // pairs with an instance this window changed or gave birth to: the others were judged,
        // as they are, by an earlier fusion.
        let touched: Vec<bool> = (0..self.instances.len())
            .map(|j| j >= matched.len() || matched[j])
            .collect();
        let folded = self.fold_duplicates(&mut keep, &touched, same_kind);
        report.record_folds(folded);
        self.clear_beyond_radius(views, &mut keep, &mut report);
        self.retain_marked(&keep);
        self.look_past_ends(views);
        self.keep_keyframes(views);
        Ok(report)
    }

    /// Each window instance into the persistent instance association chose for it (with the
    /// duplicates it revealed folded into the oldest of them), or born under a new id. Returns,
    /// per persistent instance, whether it was matched and whether it was absorbed.
    fn merge_or_birth(
        &mut self,
        window: Vec<WindowInstance>,
        association: &Association,
        duplicates: &[Vec<usize>],
        sighting: Sighting<'_>,
        report: &mut FusionReport,
    ) -> (Vec<bool>, Vec<bool>) {
        let p = self.params;
        let mut matched = vec![false; self.instances.len()];
        let mut absorbed = vec![false; self.instances.len()];
        // Where an absorbed instance went: several window instances may have chosen it.
        let mut survivor: Vec<usize> = (0..self.instances.len()).collect();
        for (i, w) in window.into_iter().enumerate() {
            let range_noise = sighting.range_noise[i];
            match association.pairs[i] {
                Some(j) => {
                    let mut j = j;
                    while survivor[j] != j {
                        j = survivor[j];
                    }
                    matched[j] = true;
                    // Fold duplicates into the oldest of them (ids only ever grow).
                    let mut group: Vec<usize> = std::iter::once(j)
                        .chain(duplicates[i].iter().copied().filter(|&d| !absorbed[d]))
                        .collect();
                    group.sort_by_key(|&k| birth_order(&self.instances[k]));
                    let j = group[0];
                    for &d in &group[1..] {
                        absorbed[d] = true;
                        survivor[d] = j;
                        matched[d] = true;
                        let duplicate = self.instances[d].clone();
                        tracing::debug!(
                            absorbed = %duplicate.id,
                            survivor = %self.instances[j].id,
                            "fold: a duplicate the sighting revealed"
                        );
                        report
                            .absorbed
                            .push((duplicate.id.clone(), self.instances[j].id.clone()));
                        self.instances[j].absorb(&duplicate, p);
                    }
                    matched[j] = true;
                    let m = &mut self.instances[j];
                    m.observe_from(sighting.viewpoint, w.gaussians.len() as f32);
                    m.observe_noise(range_noise, w.gaussians.len() as f32);
                    m.merge(&w.gaussians, &w.prototype, w.support.max(1) as f64, p);
                    m.confidence = (m.confidence + p.confirm_gain).min(1.0);
                    m.observations += 1;
                    m.last_seen_nanos = sighting.stamp_nanos;
                    tracing::debug!(
                        window_instance = i,
                        gaussians = w.gaussians.len(),
                        instance = %m.id,
                        as_part = association.from_parts[i],
                        "sighting"
                    );
                    report.assigned.push(m.id.clone());
                    report.merged += 1;
                }
                None => {
                    let id = self.new_id();
                    tracing::debug!(
                        window_instance = i,
                        gaussians = w.gaussians.len(),
                        instance = %id,
                        "birth"
                    );
                    report.assigned.push(id.clone());
                    self.instances.push(born(id, w, sighting, range_noise, p));
                    report.born += 1;
                }
            }
        }
        (matched, absorbed)
    }

    /// Evidence that instances are different objects: the persistent instances this window's
    /// instances matched (not those it gave birth to: a window that cuts one object in two makes
    /// two newborns, which the fragment rule may still join), taken pairwise.
    fn record_seen_apart(&mut self, association: &Association, report: &FusionReport) {
        let mut matched: Vec<&String> = association
            .pairs
            .iter()
            .zip(&report.assigned)
            .filter(|(pair, _)| pair.is_some())
            .map(|(_, id)| id)
            .collect();
        matched.sort();
        matched.dedup();
        for (k, a) in matched.iter().enumerate() {
            for b in &matched[k + 1..] {
                self.seen_apart.insert(((*a).clone(), (*b).clone()));
            }
        }
    }

    /// Evidence from the splits ([`SceneMap::split_where_seen_as_two`]): the instance a window
    /// saw as two and the one born from its part were seen apart.
    fn record_split_apart(&mut self, splits: &[(usize, usize)], report: &FusionReport) {
        for &(kept, part) in splits {
            let (a, b) = (&report.assigned[kept], &report.assigned[part]);
            self.seen_apart.insert((a.min(b).clone(), a.max(b).clone()));
        }
    }

    /// [`SceneMap::seen_apart`] as pairs of indices into `instances` (the smaller first).
    fn seen_apart_indices(&self) -> rustc_hash::FxHashSet<(usize, usize)> {
        if self.seen_apart.is_empty() {
            return Default::default();
        }
        let index: rustc_hash::FxHashMap<&str, usize> = self
            .instances
            .iter()
            .enumerate()
            .map(|(k, i)| (i.id.as_str(), k))
            .collect();
        self.seen_apart
            .iter()
            .filter_map(|(a, b)| {
                let (a, b) = (*index.get(a.as_str())?, *index.get(b.as_str())?);
                Some((a.min(b), a.max(b)))
            })
            .collect()
    }

    /// Whether a window saw instances `a` and `b` as two objects ([`SceneMap::seen_apart`]).
    pub fn seen_apart(&self, a: &str, b: &str) -> bool {
        let pair = if a <= b { (a, b) } else { (b, a) };
        self.seen_apart
            .contains(&(pair.0.to_owned(), pair.1.to_owned()))
    }

    /// Unmatched instances where some window view sees free space lose confidence; those left
    /// without any die (`keep` false).
    fn lose_confidence_where_seen_through(
        &mut self,
        matched: &[bool],
        views: &[WindowView],
        keep: &mut [bool],
        report: &mut FusionReport,
    ) {
        let p = self.params;
        for (j, instance) in self.instances.iter_mut().enumerate() {
            if j >= matched.len() || matched[j] {
                continue;
            }
            let expected = views.iter().any(|view| {
                let (fraction, inside) =
                    seen_through_fraction(&instance.gaussians, view, p.depth_tolerance);
                inside > 0 && fraction >= p.visible_fraction
            });
            if expected {
                instance.confidence -= p.miss_penalty;
                report.missed += 1;
                if instance.confidence <= 0.0 {
                    keep[j] = false;
                    report.died += 1;
                }
            }
        }
    }

    /// Instances farther than the clearing radius from the newest camera are dropped.
    fn clear_beyond_radius(
        &self,
        views: &[WindowView],
        keep: &mut [bool],
        report: &mut FusionReport,
    ) {
        let Some(newest) = views.iter().max_by_key(|v| v.keyframe.stamp_nanos) else {
            return;
        };
        let here = newest.keyframe.world_from_camera.translation.as_vec3();
        for (j, instance) in self.instances.iter().enumerate() {
            if keep[j] && instance.center().distance(here) > self.params.clearing_radius {
                keep[j] = false;
                report.cleared += 1;
            }
        }
    }

    /// Where the window's views see free space just beyond an instance's ends, it keeps those
    /// points ([`Instance::seen_free`]): its object ends before them. Every instance, seen by the
    /// window or not: a view past the end of a table it does not group is evidence all the same.
    fn look_past_ends(&mut self, views: &[WindowView]) {
        let tolerance = self.params.depth_tolerance;
        for instance in &mut self.instances {
            if !views.iter().any(|view| in_view(instance.center(), view)) {
                continue;
            }
            let probes = probes_beyond(&instance.gaussians.means);
            if probes.is_empty() {
                continue;
            }
            let free: Vec<Vec3> = views
                .iter()
                .flat_map(|view| seen_free(&probes, view, tolerance))
                .collect();
            instance.remember_free(free);
        }
    }

    /// The window's keyframes join the map's, the oldest beyond the limit dropped.
    fn keep_keyframes(&mut self, views: &[WindowView]) {
        for view in views {
            self.keyframes.push_back(view.keyframe.clone());
        }
        while self.keyframes.len() > self.params.max_keyframes {
            self.keyframes.pop_front();
        }
    }

    /// [`SceneMap::fuse`], then [`SceneMap::fold_fragments`] with `kinds`, and both fold rules
    /// again over what each fold grew until neither folds; the report's ids follow the folds (a
    /// window instance assigned to a fragment that folded is reported with the instance it went
    /// into). A map built by fusion has no pair left that either rule would fold.
    pub fn fuse_named(
        &mut self,
        window: Vec<WindowInstance>,
        views: &[WindowView],
        stamp_nanos: i64,
        kinds: impl Kinds,
    ) -> Result<FusionReport, GraphError> {
        let same_kind = |a: &[f32], b: &[f32]| kinds.same_kind(a, b);
        let mut report = self.fuse_with(window, views, stamp_nanos, &kinds)?;
        // Pairs are judged again only where an instance changed: this window's (any other pair
        // was judged, as it is, by an earlier fusion), then, rule after rule, the survivors of
        // the last folds, until neither rule folds anything.
        let changed: rustc_hash::FxHashSet<String> = report
            .assigned
            .iter()
            .chain(report.absorbed.iter().map(|(_, survivor)| survivor))
            .cloned()
            .collect();
        let mut touched = self.marks(&changed);
        loop {
            let folded = self.fold_fragments_of(&kinds, &touched);
            let survivors = report.record_folds(folded);
            if survivors.is_empty() {
                break;
            }
            let mut keep = vec![true; self.instances.len()];
            let folded = self.fold_duplicates(&mut keep, &self.marks(&survivors), &same_kind);
            self.retain_marked(&keep);
            let survivors = report.record_folds(folded);
            if survivors.is_empty() {
                break;
            }
            touched = self.marks(&survivors);
        }
        Ok(report)
    }

    /// For each instance, whether `ids` holds its id.
    fn marks(&self, ids: &rustc_hash::FxHashSet<String>) -> Vec<bool> {
        self.instances.iter().map(|i| ids.contains(&i.id)).collect()
    }

    /// Drop the instances `keep` does not mark, and the evidence about them.
    fn retain_marked(&mut self, keep: &[bool]) {
        let mut index = 0;
        self.instances.retain(|_| {
            index += 1;
            keep[index - 1]
        });
        if keep.iter().all(|k| *k) {
            return;
        }
        let alive: rustc_hash::FxHashSet<&str> =
            self.instances.iter().map(|i| i.id.as_str()).collect();
        self.seen_apart
            .retain(|(a, b)| alive.contains(a.as_str()) && alive.contains(b.as_str()));
    }
}

/// Where and when a window saw its instances: the mean camera centre, each instance's range
/// noise, the window's stamp.
#[derive(Debug, Clone, Copy)]
struct Sighting<'a> {
    viewpoint: Option<Vec3>,
    range_noise: &'a [Option<f32>],
    stamp_nanos: i64,
}

/// The range noise each window instance was measured through: σ₁ · r² at its distance from the
/// window's mean camera centre (`None` where the views measured none).
fn range_noise_of(
    window: &[WindowInstance],
    views: &[WindowView],
    viewpoint: Option<Vec3>,
) -> Vec<Option<f32>> {
    let noise_at_1m = median_measured(views.iter().map(|v| v.depth_noise_at_1m));
    window
        .iter()
        .map(|w| {
            let centroid = w.gaussians.means.iter().sum::<Vec3>() / w.gaussians.len().max(1) as f32;
            let range = viewpoint?.distance(centroid);
            Some(noise_at_1m? * range * range).filter(|s| s.is_finite())
        })
        .collect()
}

/// Every window instance holds valid Gaussians, at least one.
fn validate(window: &[WindowInstance]) -> Result<(), GraphError> {
    for (i, w) in window.iter().enumerate() {
        w.gaussians
            .validate()
            .map_err(|e| GraphError::BadInstance(i, e.to_string()))?;
        if w.gaussians.is_empty() {
            return Err(GraphError::BadInstance(i, "no Gaussians".into()));
        }
    }
    Ok(())
}

/// A new persistent instance of window instance `w`.
fn born(
    id: String,
    w: WindowInstance,
    sighting: Sighting<'_>,
    range_noise: Option<f32>,
    p: FusionParams,
) -> Instance {
    let seen_by = w.gaussians.len() as f32;
    let mut born = Instance {
        id,
        gaussians: capped(w.gaussians, p.voxel, p.max_gaussians_per_instance),
        prototype: w.prototype,
        prototype_weight: w.support.max(1) as f64,
        confidence: p.birth_confidence,
        observations: 1,
        first_seen_nanos: sighting.stamp_nanos,
        last_seen_nanos: sighting.stamp_nanos,
        viewpoint: None,
        viewpoint_weight: 0.0,
        range_noise_m: 0.0,
        range_noise_weight: 0.0,
        seen_free: Vec::new(),
    };
    born.observe_from(sighting.viewpoint, seen_by);
    born.observe_noise(range_noise, seen_by);
    born
}

#[cfg(test)]
mod tests;
