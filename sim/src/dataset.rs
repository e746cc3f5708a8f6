//! Training datasets on disk: one directory per procedural scene with `views` overlapping views
//! along the robot's random walk (the stretch of the walk that sees the most objects).
//!
//! ```text
//! <out>/dataset.json                 split, resolution, views, class table, statistics
//! <out>/<scene>/cameras.json         per view: files, K, world_from_camera; the object list
//! <out>/<scene>/view_NN_rgb.png      8-bit RGB
//! <out>/<scene>/view_NN_depth.png    16-bit depth in millimetres (0 = invalid)
//! <out>/<scene>/view_NN_instance.png 16-bit instance ids (0 = room)
//! <out>/<scene>/view_NN_class.png    16-bit class ids (0 = room; see dataset.json)
//! ```

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use rayon::prelude::*;
use serde::Serialize;

use crate::effects::Preset;
use crate::library;
use crate::procedural::{generate_with, ProceduralOptions, Split};
use crate::simulation::{SimView, Simulation};

#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {reason}")]
    Image { path: PathBuf, reason: String },
    #[error("scene {0}: {1}")]
    Scene(String, String),
    #[error("{0}")]
    Invalid(String),
}

pub type Result<T> = std::result::Result<T, DatasetError>;

/// Format version of `dataset.json` / `cameras.json`.
pub const FORMAT_VERSION: u32 = 1;

#[derive(Debug, Clone, PartialEq)]
pub struct DatasetOptions {
    pub split: Split,
    /// Scene index of the first sample in the split.
    pub first_index: u64,
    pub samples: usize,
    pub views: usize,
    /// Frames of the walk between consecutive views (at 10 Hz and 0.3 m/s: 3 cm per frame).
    pub frames_between_views: usize,
    pub width: u32,
    pub height: u32,
    pub fov_x_deg: f64,
    /// Effects drawn per sample from this preset ([`Preset::sample_effects`]); `None` renders
    /// clean.
    pub effects: Option<Preset>,
    /// Render at this sensor resolution and resample to `width × height` as the node does
    /// ([`crate::resample`]), so effects act at the scale the node meets them; `None` renders
    /// at `width × height`.
    pub sensor: Option<(u32, u32)>,
}

impl Default for DatasetOptions {
    fn default() -> Self {
        Self {
            split: Split::Train,
            first_index: 0,
            samples: 100,
            views: 4,
            frames_between_views: 6,
            width: 128,
            height: 96,
            fov_x_deg: 90.0,
            effects: None,
            sensor: None,
        }
    }
}

#[derive(Debug, Serialize)]
struct ClassEntry {
    id: u16,
    name: &'static str,
    description: &'static str,
    affordances: &'static [&'static str],
}

#[derive(Debug, Serialize)]
struct DatasetManifest<'a> {
    format: &'static str,
    version: u32,
    split: Split,
    first_index: u64,
    samples: usize,
    views: usize,
    width: u32,
    height: u32,
    fov_x_deg: f64,
    depth_scale: f64,
    /// The effects preset samples were drawn from (`clean` when none).
    effects: String,
    /// The resolution views were rendered at before resampling (`null`: rendered at `width ×
    /// height`).
    sensor: Option<[u32; 2]>,
    classes: Vec<ClassEntry>,
    scenes: &'a [String],
    /// Share of pixels showing an object (not the room), over all views.
    object_pixel_fraction: f64,
}

#[derive(Debug, Serialize)]
struct ViewEntry {
    frame: usize,
    rgb: String,
    depth: String,
    instance: String,
    class: String,
    width: u32,
    height: u32,
    /// Row-major 3×3 intrinsics.
    k: [f64; 9],
    /// Row-major 4×4 `world_from_camera`, REP-103 optical frame (z forward, x right, y down).
    world_from_camera: [[f64; 4]; 4],
}

#[derive(Debug, Serialize)]
struct ObjectEntry {
    instance_id: u16,
    class_id: u16,
    class: &'static str,
    color: [f32; 3],
    position: [f64; 3],
    yaw: f64,
    bounds_min: [f64; 3],
    bounds_max: [f64; 3],
    support: Option<u16>,
}

#[derive(Debug, Serialize)]
struct SampleManifest {
    version: u32,
    scene: String,
    seed: u64,
    views: Vec<ViewEntry>,
    objects: Vec<ObjectEntry>,
}

/// What a finished dataset holds.
#[derive(Debug, Clone, PartialEq)]
pub struct DatasetSummary {
    pub samples: usize,
    pub views: usize,
    pub bytes: u64,
    pub object_pixel_fraction: f64,
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> DatasetError + '_ {
    move |source| DatasetError::Io {
        path: path.to_owned(),
        source,
    }
}

fn save_png(
    path: &Path,
    width: u32,
    height: u32,
    data: &[u8],
    color: image::ExtendedColorType,
) -> Result<u64> {
    image::save_buffer_with_format(path, data, width, height, color, image::ImageFormat::Png)
        .map_err(|e| DatasetError::Image {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
    Ok(std::fs::metadata(path).map_err(io(path))?.len())
}

/// 16-bit samples as `image`'s encoders take them: native byte order (PNG's big-endian order is
/// the encoder's business).
fn ne16(values: impl Iterator<Item = u16>) -> Vec<u8> {
    values.flat_map(u16::to_ne_bytes).collect()
}

fn write_view(dir: &Path, index: usize, frame: usize, view: &SimView) -> Result<(ViewEntry, u64)> {
    let (w, h) = (view.truth.width, view.truth.height);
    let name = |kind: &str| format!("view_{index:02}_{kind}.png");
    let mut bytes = save_png(
        &dir.join(name("rgb")),
        w,
        h,
        view.sensor_rgb(),
        image::ExtendedColorType::Rgb8,
    )?;
    let millimetres = ne16(view.sensor_depth().iter().map(|z| {
        if z.is_finite() {
            (z * 1000.0).round().clamp(0.0, 65535.0) as u16
        } else {
            0
        }
    }));
    bytes += save_png(
        &dir.join(name("depth")),
        w,
        h,
        &millimetres,
        image::ExtendedColorType::L16,
    )?;
    for (kind, ids) in [
        ("instance", &view.truth.instance),
        ("class", &view.truth.class),
    ] {
        let pixels = ne16(ids.iter().copied());
        bytes += save_png(
            &dir.join(name(kind)),
            w,
            h,
            &pixels,
            image::ExtendedColorType::L16,
        )?;
    }
    let c = &view.pinhole;
    let m = glam::DMat4::from_rotation_translation(view.rotation, view.position).transpose();
    let entry = ViewEntry {
        frame,
        rgb: name("rgb"),
        depth: name("depth"),
        instance: name("instance"),
        class: name("class"),
        width: w,
        height: h,
        k: [c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0],
        world_from_camera: [
            m.x_axis.to_array(),
            m.y_axis.to_array(),
            m.z_axis.to_array(),
            m.w_axis.to_array(),
        ],
    };
    Ok((entry, bytes))
}

/// Window starts considered along the walk (every `frames_between_views` frames).
const CANDIDATE_STARTS: usize = 8;

/// The window start whose views see the most object pixels (judged on 32×24 renders), so samples
/// show objects rather than bare walls.
fn busiest_window_start(sim: &Simulation, options: &DatasetOptions) -> usize {
    let camera = &sim.file.cameras[0];
    let probe = crate::render::Pinhole::from_fov(32, 24, camera.fov_x_deg.to_radians());
    let score = |start: usize| -> usize {
        (0..options.views)
            .map(|v| {
                let pose = sim.poses[start + v * options.frames_between_views];
                let (rotation, position) = crate::scene::camera_pose(camera, &pose);
                let view = crate::render::render(&sim.scene, &probe, rotation, position);
                view.instance.iter().filter(|i| **i != 0).count()
            })
            .sum()
    };
    (0..CANDIDATE_STARTS)
        .map(|k| k * options.frames_between_views)
        .max_by_key(|&start| (score(start), std::cmp::Reverse(start)))
        .unwrap_or(0)
}

/// One sample: returns (scene name, bytes written, object pixels, pixels).
fn write_sample(
    out: &Path,
    options: &DatasetOptions,
    index: u64,
) -> Result<(String, u64, usize, usize)> {
    let window = (options.views - 1) * options.frames_between_views + 1;
    let (render_width, render_height) = options.sensor.unwrap_or((options.width, options.height));
    let procedural = ProceduralOptions {
        width: render_width,
        height: render_height,
        fov_x_deg: options.fov_x_deg,
        frames: window + CANDIDATE_STARTS * options.frames_between_views,
        rate_hz: 10.0,
    };
    let mut file = generate_with(options.split, index, &procedural)
        .ok_or_else(|| DatasetError::Invalid(format!("no scene {index} in {}", options.split)))?;
    if let Some(preset) = options.effects {
        file.effects = preset.sample_effects(file.seed);
    }
    let name = file.name.clone();
    let sim =
        Simulation::new(file).map_err(|e| DatasetError::Scene(name.clone(), e.to_string()))?;
    let dir = out.join(&name);
    std::fs::create_dir_all(&dir).map_err(io(&dir))?;
    let start = busiest_window_start(&sim, options);
    let classes = library::classes();
    let mut views = Vec::new();
    let (mut bytes, mut object_pixels, mut pixels) = (0, 0, 0);
    for v in 0..options.views {
        let frame_index = start + v * options.frames_between_views;
        let frame = sim.frame(frame_index);
        let resampled;
        let view = if options.sensor.is_some() {
            resampled = crate::resample::view_at(&frame.views[0], options.width, options.height);
            &resampled
        } else {
            &frame.views[0]
        };
        object_pixels += view.truth.instance.iter().filter(|i| **i != 0).count();
        pixels += view.truth.instance.len();
        let (entry, written) = write_view(&dir, v, frame_index, view)?;
        views.push(entry);
        bytes += written;
    }
    let objects = sim
        .scene
        .objects
        .iter()
        .map(|o| {
            let (lo, hi) = o.bounds();
            ObjectEntry {
                instance_id: o.instance_id,
                class_id: o.class_id,
                class: classes
                    .iter()
                    .find(|c| c.id == o.class_id)
                    .map_or("unknown", |c| c.name),
                color: o.color,
                position: o.position.to_array(),
                yaw: o.yaw,
                bounds_min: lo.to_array(),
                bounds_max: hi.to_array(),
                support: o.support,
            }
        })
        .collect();
    let manifest = SampleManifest {
        version: FORMAT_VERSION,
        scene: name.clone(),
        seed: sim.file.seed,
        views,
        objects,
    };
    let path = dir.join("cameras.json");
    let json =
        serde_json::to_vec_pretty(&manifest).map_err(|e| DatasetError::Invalid(e.to_string()))?;
    std::fs::write(&path, &json).map_err(io(&path))?;
    Ok((name, bytes + json.len() as u64, object_pixels, pixels))
}

/// Write a dataset; `progress` is called with the number of samples done.
pub fn write_dataset(
    out: &Path,
    options: &DatasetOptions,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<DatasetSummary> {
    if options.views == 0 || options.samples == 0 || options.frames_between_views == 0 {
        return Err(DatasetError::Invalid(
            "a dataset needs samples, views and frames between views".into(),
        ));
    }
    std::fs::create_dir_all(out).map_err(io(out))?;
    let done = AtomicUsize::new(0);
    let results: Vec<(String, u64, usize, usize)> = (0..options.samples as u64)
        .into_par_iter()
        .map(|i| {
            let result = write_sample(out, options, options.first_index + i);
            progress(done.fetch_add(1, Ordering::Relaxed) + 1);
            result
        })
        .collect::<Result<_>>()?;
    let scenes: Vec<String> = results.iter().map(|r| r.0.clone()).collect();
    let object_pixels: usize = results.iter().map(|r| r.2).sum();
    let pixels: usize = results.iter().map(|r| r.3).sum::<usize>().max(1);
    let fraction = object_pixels as f64 / pixels as f64;
    let manifest = DatasetManifest {
        format: "groupforward-sim-dataset",
        version: FORMAT_VERSION,
        split: options.split,
        first_index: options.first_index,
        samples: options.samples,
        views: options.views,
        width: options.width,
        height: options.height,
        fov_x_deg: options.fov_x_deg,
        depth_scale: 0.001,
        effects: options
            .effects
            .map_or_else(|| "clean".to_owned(), |p| p.name()),
        sensor: options.sensor.map(|(w, h)| [w, h]),
        classes: library::classes()
            .into_iter()
            .map(|c| ClassEntry {
                id: c.id,
                name: c.name,
                description: c.description,
                affordances: c.affordances,
            })
            .collect(),
        scenes: &scenes,
        object_pixel_fraction: fraction,
    };
    let path = out.join("dataset.json");
    let json =
        serde_json::to_vec_pretty(&manifest).map_err(|e| DatasetError::Invalid(e.to_string()))?;
    std::fs::write(&path, &json).map_err(io(&path))?;
    Ok(DatasetSummary {
        samples: options.samples,
        views: options.samples * options.views,
        bytes: results.iter().map(|r| r.1).sum::<u64>() + json.len() as u64,
        object_pixel_fraction: fraction,
    })
}
