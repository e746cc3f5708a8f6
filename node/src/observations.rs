//! The camera's own pictures of each instance, kept for the evidence a VLM is shown: per
//! persistent instance, its best few observations (the views that saw most of it), each a colour
//! crop of the camera image around the instance with its local context and the instance's mask
//! there. Memory is bounded per instance ([`OBSERVATIONS_PER_INSTANCE`] crops of at most
//! [`CROP_MAX_SIDE`] pixels a side), and instances that leave the map take theirs with them.

use std::borrow::Cow;
use std::collections::HashMap;
use std::sync::Arc;

use crate::frame::{undistort_image, Keyframe, RgbImage, SyncedFrame};
use crate::model::reconstruction::resized_camera;
use crate::recon::camera::{Camera, PlumbBob};

/// Observations kept per instance: the views that saw most of its pixels. With
/// [`CROP_MAX_SIDE`], sized to the bound: 2 × 120² × (3 colour + 1 mask) bytes is
/// 57.6 MB at 500 instances, under 64 MB.
pub const OBSERVATIONS_PER_INSTANCE: usize = 2;
/// A crop's longer side at most (pixels): larger ones are scaled down to it (see above).
pub const CROP_MAX_SIDE: usize = 120;
/// The crop holds the instance's pixels grown by this share of their extent on every side: its
/// local context, twice its extent across (a choice, not fitted).
pub const CONTEXT_MARGIN: f64 = 0.5;
/// An instance covering fewer model pixels in a view is not kept from it (a sliver: 4 × 4 of
/// the model's 128 × 96; a choice, not fitted).
pub const MIN_OBSERVED_PIXELS: usize = 16;

/// One view of one instance.
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    pub stamp_nanos: i64,
    /// The instance's pixels in the window's model view (what ranks observations).
    pub pixels: usize,
    /// The camera image around it (its extent and context), at the camera's resolution unless
    /// that exceeds [`CROP_MAX_SIDE`].
    pub image: RgbImage,
    /// Per pixel of `image`: the instance is there.
    pub mask: Vec<bool>,
}

impl Observation {
    /// Bytes held by its images.
    pub fn bytes(&self) -> usize {
        self.image.data.len() + self.mask.len()
    }
}

/// The newest camera picture a window saw, undistorted, and the view it shows: what the evidence's
/// overview is drawn on (one picture at the camera's resolution: about 0.9 MB at 640 × 480).
#[derive(Debug, Clone, PartialEq)]
pub struct CameraPicture {
    /// Its pose, stamp and camera (the camera's intrinsics, without distortion: the image is
    /// undistorted).
    pub keyframe: Keyframe,
    pub image: RgbImage,
}

/// The kept observations, by persistent instance id, and the newest camera picture. Cheap to
/// clone (observations are shared).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Observations {
    by_instance: HashMap<String, Vec<Arc<Observation>>>,
    newest: Option<Arc<CameraPicture>>,
}

/// A window's view as the store reads it: the camera frame, and per model pixel (`width` ×
/// `height`, row-major) the persistent id of the instance there, if any.
#[derive(Debug)]
pub struct ObservedView<'a> {
    pub frame: &'a SyncedFrame,
    pub width: usize,
    pub height: usize,
    pub owners: Vec<Option<&'a str>>,
}

impl Observations {
    /// The observations of instance `id`, best first.
    pub fn of(&self, id: &str) -> &[Arc<Observation>] {
        self.by_instance.get(id).map_or(&[], Vec::as_slice)
    }

    /// The newest camera picture kept ([`Observations::add_view`]).
    pub fn newest(&self) -> Option<&CameraPicture> {
        self.newest.as_deref()
    }

    /// Instances with observations.
    pub fn len(&self) -> usize {
        self.by_instance.len()
    }

    pub fn is_empty(&self) -> bool {
        self.by_instance.is_empty()
    }

    /// Bytes held by every kept image.
    pub fn bytes(&self) -> usize {
        let newest = self.newest.as_ref().map_or(0, |n| n.image.data.len());
        newest
            + self
                .by_instance
                .values()
                .flatten()
                .map(|o| o.bytes())
                .sum::<usize>()
    }

    /// Keep what `view` shows of each instance where it beats that instance's kept ones, and
    /// its picture when it is the newest ([`Observations::add_views`] of one view).
    pub fn add_view(&mut self, view: &ObservedView<'_>) {
        self.add_views(std::slice::from_ref(view));
    }

    /// Keep what each of a window's `views` shows of each instance where it beats that
    /// instance's kept ones, and the picture of the newest of them when it is newer than the one
    /// kept (one picture per window: the others would be replaced at once).
    pub fn add_views(&mut self, views: &[ObservedView<'_>]) {
        let newest = views
            .iter()
            .enumerate()
            .max_by_key(|(_, v)| v.frame.stamp_nanos)
            .map(|(k, _)| k);
        for (k, view) in views.iter().enumerate() {
            // The model saw the undistorted image: crops come from the same one, undistorted
            // once for the view and only when something is kept from it.
            let mut image: Option<Cow<'_, RgbImage>> = None;
            self.keep_instances(view, &mut image);
            if Some(k) == newest {
                self.keep_picture(view.frame, image);
            }
        }
    }

    /// `frame`'s picture (`image`: its undistorted picture, if made already) as the newest,
    /// unless a newer one is kept.
    fn keep_picture(&mut self, frame: &SyncedFrame, image: Option<Cow<'_, RgbImage>>) {
        if self
            .newest
            .as_ref()
            .is_some_and(|n| n.keyframe.stamp_nanos > frame.stamp_nanos)
        {
            return;
        }
        let image = image.unwrap_or_else(|| undistorted(frame)).into_owned();
        let camera = resized_camera(&frame.camera, image.width as usize, image.height as usize);
        self.newest = Some(Arc::new(CameraPicture {
            keyframe: Keyframe {
                stamp_nanos: frame.stamp_nanos,
                camera: Camera {
                    distortion: PlumbBob::default(),
                    ..camera
                },
                world_from_camera: frame.world_from_camera,
            },
            image,
        }));
    }

    /// What `view` shows of each instance, where it beats that instance's kept ones; `image` is
    /// the view's undistorted picture once something needed it.
    fn keep_instances<'a>(
        &mut self,
        view: &ObservedView<'a>,
        image: &mut Option<Cow<'a, RgbImage>>,
    ) {
        for (id, extent) in extents(view) {
            if extent.pixels < MIN_OBSERVED_PIXELS {
                continue;
            }
            let kept = self.of(id);
            let worst = kept.iter().map(|o| o.pixels).min().unwrap_or(0);
            if kept.len() >= OBSERVATIONS_PER_INSTANCE && extent.pixels <= worst {
                continue;
            }
            let image = image.get_or_insert_with(|| undistorted(view.frame));
            let Some(observation) = observe(view, image, id, &extent) else {
                continue;
            };
            let kept = self.by_instance.entry(id.to_owned()).or_default();
            keep_best(kept, [Arc::new(observation)]);
        }
    }

    /// Follow the map's folds (absorbed id, surviving id): the survivor keeps the best of both.
    pub fn follow_folds(&mut self, folds: &[(String, String)]) {
        for (absorbed, survivor) in folds {
            if let Some(moved) = self.by_instance.remove(absorbed) {
                keep_best(self.by_instance.entry(survivor.clone()).or_default(), moved);
            }
        }
    }

    /// Drop the observations of instances `live` says are gone.
    pub fn retain(&mut self, live: impl Fn(&str) -> bool) {
        self.by_instance.retain(|id, _| live(id));
    }
}

/// The frame's picture as the model saw it: undistorted (borrowed where it has no distortion).
fn undistorted(frame: &SyncedFrame) -> Cow<'_, RgbImage> {
    if frame.camera.distortion.is_zero() {
        Cow::Borrowed(&frame.rgb)
    } else {
        Cow::Owned(undistort_image(&frame.camera, &frame.rgb))
    }
}

/// `kept` with `more`, the best [`OBSERVATIONS_PER_INSTANCE`] of them, best first.
fn keep_best(kept: &mut Vec<Arc<Observation>>, more: impl IntoIterator<Item = Arc<Observation>>) {
    kept.extend(more);
    kept.sort_by_key(|o| std::cmp::Reverse(o.pixels));
    kept.truncate(OBSERVATIONS_PER_INSTANCE);
}

/// Where an instance lies in a model view: its pixel count and bounds (inclusive).
struct Extent {
    pixels: usize,
    lo: (usize, usize),
    hi: (usize, usize),
}

fn extents<'a>(view: &ObservedView<'a>) -> HashMap<&'a str, Extent> {
    let mut out: HashMap<&str, Extent> = HashMap::new();
    for (p, owner) in view.owners.iter().enumerate() {
        let Some(id) = owner else { continue };
        let (x, y) = (p % view.width.max(1), p / view.width.max(1));
        let e = out.entry(id).or_insert(Extent {
            pixels: 0,
            lo: (x, y),
            hi: (x, y),
        });
        e.pixels += 1;
        e.lo = (e.lo.0.min(x), e.lo.1.min(y));
        e.hi = (e.hi.0.max(x), e.hi.1.max(y));
    }
    out
}

/// The crop of `image` (`view`'s camera image, undistorted) around `extent` (grown by the context margin), scaled
/// down to [`CROP_MAX_SIDE`] where larger, with `id`'s mask sampled from the model pixels.
fn observe(
    view: &ObservedView<'_>,
    image: &RgbImage,
    id: &str,
    extent: &Extent,
) -> Option<Observation> {
    let (iw, ih) = (image.width as usize, image.height as usize);
    if iw == 0 || ih == 0 || image.data.len() < iw * ih * 3 || view.width == 0 || view.height == 0 {
        return None;
    }
    // Model pixel -> camera pixel scale.
    let (sx, sy) = (
        iw as f64 / view.width as f64,
        ih as f64 / view.height as f64,
    );
    let (w, h) = (
        (extent.hi.0 + 1 - extent.lo.0) as f64,
        (extent.hi.1 + 1 - extent.lo.1) as f64,
    );
    let x0 = ((extent.lo.0 as f64 - CONTEXT_MARGIN * w) * sx).max(0.0) as usize;
    let y0 = ((extent.lo.1 as f64 - CONTEXT_MARGIN * h) * sy).max(0.0) as usize;
    let x1 = (((extent.hi.0 + 1) as f64 + CONTEXT_MARGIN * w) * sx).min(iw as f64) as usize;
    let y1 = (((extent.hi.1 + 1) as f64 + CONTEXT_MARGIN * h) * sy).min(ih as f64) as usize;
    if x1 <= x0 || y1 <= y0 {
        return None;
    }
    let scale = (CROP_MAX_SIDE as f64 / (x1 - x0).max(y1 - y0) as f64).min(1.0);
    let (cw, ch) = (
        (((x1 - x0) as f64 * scale).round() as usize).max(1),
        (((y1 - y0) as f64 * scale).round() as usize).max(1),
    );
    let mut data = Vec::with_capacity(cw * ch * 3);
    let mut mask = Vec::with_capacity(cw * ch);
    for cy in 0..ch {
        let y = (y0 + ((cy as f64 + 0.5) / scale) as usize).min(y1 - 1);
        for cx in 0..cw {
            let x = (x0 + ((cx as f64 + 0.5) / scale) as usize).min(x1 - 1);
            data.extend_from_slice(&image.data[(y * iw + x) * 3..(y * iw + x) * 3 + 3]);
            let (mx, my) = (
                ((x as f64 / sx) as usize).min(view.width - 1),
                ((y as f64 / sy) as usize).min(view.height - 1),
            );
            mask.push(view.owners.get(my * view.width + mx).copied().flatten() == Some(id));
        }
    }
    Some(Observation {
        stamp_nanos: view.frame.stamp_nanos,
        pixels: extent.pixels,
        image: RgbImage {
            width: cw as u32,
            height: ch as u32,
            data,
        },
        mask,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::camera::Camera;
    use crate::recon::Rigid;

    /// A 320 × 240 camera frame whose pixel (x, y) is coloured (x, y, 7) / 4, and the model's
    /// 80 × 60 view of it with `id` over the model pixels in `rect` (x0, y0, x1, y1 exclusive).
    fn frame(stamp_nanos: i64) -> SyncedFrame {
        let (w, h) = (320u32, 240u32);
        let data = (0..w * h)
            .flat_map(|p| [((p % w) / 4) as u8, ((p / w) / 4) as u8, 7])
            .collect();
        SyncedFrame {
            camera_name: "front".into(),
            stamp_nanos,
            frame_id: "camera".into(),
            rgb: RgbImage {
                width: w,
                height: h,
                data,
            },
            depth: None,
            camera: Camera::from_fov(w, h, 1.5).unwrap(),
            world_from_camera: Rigid::default(),
        }
    }

    fn owners(id: &'static str, rect: (usize, usize, usize, usize)) -> Vec<Option<&'static str>> {
        (0..80 * 60)
            .map(|p| {
                let (x, y) = (p % 80, p / 80);
                (x >= rect.0 && x < rect.2 && y >= rect.1 && y < rect.3).then_some(id)
            })
            .collect()
    }

    fn view<'a>(frame: &'a SyncedFrame, owners: Vec<Option<&'a str>>) -> ObservedView<'a> {
        ObservedView {
            frame,
            width: 80,
            height: 60,
            owners,
        }
    }

    #[test]
    fn an_observation_is_the_camera_s_own_pixels_around_the_instance_with_its_mask() {
        let f = frame(1);
        let mut store = Observations::default();
        // 10 × 6 model pixels at (20, 30): 40 × 24 camera pixels at (80, 120).
        store.add_view(&view(&f, owners("inst_000001", (20, 30, 30, 36))));
        let [o] = store.of("inst_000001") else {
            panic!("one observation")
        };
        // Grown by half its extent each side, at the camera's resolution: 80 × 48.
        assert_eq!((o.image.width, o.image.height), (80, 48));
        assert_eq!(o.pixels, 60);
        // Its top-left pixel is the camera's (60, 108): colour (15, 27, 7).
        assert_eq!(&o.image.data[..3], &[15, 27, 7]);
        let masked = o.mask.iter().filter(|m| **m).count();
        assert_eq!(
            masked,
            40 * 24,
            "the instance's pixels, scaled to the camera's"
        );
        assert!(
            !o.mask[0] && o.mask[(24 * 80) + 40],
            "context around, the instance inside"
        );
    }

    #[test]
    fn each_instance_keeps_its_best_views_within_a_bounded_memory() {
        let mut store = Observations::default();
        let frames: Vec<SyncedFrame> = (0..4).map(frame).collect();
        // The same instance, seen larger in each view; then a sliver.
        for (k, f) in frames.iter().enumerate() {
            store.add_view(&view(f, owners("inst_000001", (0, 0, 10 + 10 * k, 20))));
        }
        store.add_view(&view(&frames[0], owners("inst_000001", (0, 0, 2, 2))));
        let stamps: Vec<i64> = store
            .of("inst_000001")
            .iter()
            .map(|o| o.stamp_nanos)
            .collect();
        assert_eq!(
            stamps,
            vec![3, 2],
            "the two that saw most of it, best first"
        );
        // Crops larger than the cap are scaled to it.
        store.add_view(&view(&frames[0], owners("inst_000002", (0, 0, 80, 60))));
        let whole = &store.of("inst_000002")[0].image;
        assert_eq!(
            (whole.width as usize, whole.height as usize),
            (CROP_MAX_SIDE, 90)
        );
        // 500 instances each seen whole twice: at most 2 crops of 120 × 120 with their masks.
        let mut many = Observations::default();
        let ids: Vec<String> = (0..500).map(|k| format!("inst_{k:06}")).collect();
        for id in &ids {
            for f in &frames[..2] {
                many.add_view(&view(f, owners_of(id)));
            }
        }
        assert_eq!(many.len(), 500);
        // The crops, and the newest picture the overview is drawn on.
        let picture = many.newest().map_or(0, |n| n.image.data.len());
        let bound = 500 * OBSERVATIONS_PER_INSTANCE * CROP_MAX_SIDE * CROP_MAX_SIDE * 4 + picture;
        assert!(
            many.bytes() <= bound && bound <= 64 << 20,
            "{} bytes",
            many.bytes()
        );
    }

    fn owners_of(id: &str) -> Vec<Option<&str>> {
        vec![Some(id); 80 * 60]
    }

    #[test]
    fn folds_move_observations_to_the_survivor_and_gone_instances_take_theirs() {
        let f = frame(1);
        let mut store = Observations::default();
        store.add_view(&view(&f, owners("inst_000001", (0, 0, 20, 20))));
        store.add_view(&view(&f, owners("inst_000002", (40, 0, 50, 10))));
        store.follow_folds(&[("inst_000002".into(), "inst_000001".into())]);
        assert!(store.of("inst_000002").is_empty());
        assert_eq!(store.of("inst_000001").len(), 2);
        store.retain(|id| id != "inst_000001");
        // The newest picture stays: it shows the view, not an instance.
        let picture = store.newest().map(|n| n.image.data.len());
        assert!(store.is_empty() && Some(store.bytes()) == picture);
    }

    #[test]
    fn the_newest_picture_is_kept_whole_and_an_older_frame_does_not_replace_it() {
        let (older, newer) = (frame(1), frame(2));
        let mut store = Observations::default();
        store.add_view(&view(&newer, vec![None; 80 * 60]));
        store.add_view(&view(&older, owners("inst_000001", (0, 0, 20, 20))));
        let picture = store.newest().unwrap();
        assert_eq!(picture.keyframe.stamp_nanos, 2);
        assert_eq!((picture.image.width, picture.image.height), (320, 240));
        assert_eq!(picture.image, newer.rgb);
        assert!(picture.keyframe.camera.distortion.is_zero());
        // A window's views, newest first: its newest picture is kept, and the crops of all.
        let mut window = Observations::default();
        window.add_views(&[
            view(&newer, vec![None; 80 * 60]),
            view(&older, owners("inst_000001", (0, 0, 20, 20))),
        ]);
        assert_eq!(window.newest().unwrap().keyframe.stamp_nanos, 2);
        assert_eq!(window.of("inst_000001").len(), 1);
    }

    #[test]
    fn degenerate_views_keep_nothing_and_never_panic() {
        let mut f = frame(1);
        let mut store = Observations::default();
        // No pixels, a view of zero size, an image shorter than it says.
        store.add_view(&view(&f, vec![None; 80 * 60]));
        store.add_view(&ObservedView {
            frame: &f,
            width: 0,
            height: 0,
            owners: Vec::new(),
        });
        f.rgb.data.truncate(10);
        store.add_view(&view(&f, owners("inst_000001", (0, 0, 80, 60))));
        assert!(store.is_empty());
    }
}
