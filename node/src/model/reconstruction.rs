//! The reconstruction model runner (GroupForward role, ARCHITECTURE.md §5): V views in, per-pixel depth,
//! Gaussian attributes and instance embeddings out, lifted to world-space Gaussians.
//!
//! Contract: `images` f32 [1,V,3,H,W] in [0,1] (normalised as the manifest says); in RGB-D mode also
//! `points` f32 [1,V,3,H,W], world XYZ from sensor depth, centred on the window's mean camera centre
//! and divided by `points_scale`; in posed RGB mode instead `intrinsics` f32 [1,V,3,3] (pixels at the
//! model resolution) and `world_from_camera` f32 [1,V,4,4] (the TF poses in the frame of `points`:
//! translation centred on the mean camera centre and divided by `points_scale`). Outputs `depth` [1,V,H,W] (metres), `gaussians` [1,V,11,H,W]
//! = opacity (1), scale (3, pixels at unit depth), rotation (4, xyzw in the camera frame), colour
//! residual (3, added to the input colour), `embeddings` [1,V,d_e,H,W]; optionally `pose_enc` [1,V,9].

use std::path::Path;

use glam::{DMat3, DVec2, DVec3};

use super::manifest::{InputMode, Manifest, ModelKind, Normalization};
use super::{open_session, ModelError, Result, SessionOptions};
use crate::frame::{DepthImage, RgbImage, SyncedFrame};
use crate::recon::camera::Camera;
use crate::recon::gaussians::{lift, Gaussians, PixelAligned};
use crate::recon::Rigid;

/// Channels of the `gaussians` output.
pub const GAUSSIAN_CHANNELS: usize = 11;

/// One input view: colour, optional registered depth, camera and pose.
#[derive(Debug, Clone, Copy)]
pub struct View<'a> {
    pub rgb: &'a RgbImage,
    pub depth: Option<&'a DepthImage>,
    pub camera: Camera,
    pub world_from_camera: Rigid,
}

impl<'a> From<&'a SyncedFrame> for View<'a> {
    fn from(frame: &'a SyncedFrame) -> Self {
        Self {
            rgb: &frame.rgb,
            depth: frame.depth.as_ref(),
            camera: frame.camera,
            world_from_camera: frame.world_from_camera,
        }
    }
}

/// Input tensors at the model resolution: `images` [1,V,3,H,W] and what the model's mode takes
/// besides colour.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelInputs {
    pub views: usize,
    pub height: usize,
    pub width: usize,
    pub images: Vec<f32>,
    pub geometry: Geometry,
}

/// The inputs besides colour, by [`InputMode`].
#[derive(Debug, Clone, PartialEq)]
pub enum Geometry {
    /// RGB only.
    None,
    /// RGB-D: `points` [1,V,3,H,W].
    Points(Vec<f32>),
    /// Posed RGB: `intrinsics` [1,V,3,3] and `world_from_camera` [1,V,4,4], row-major.
    Cameras {
        intrinsics: Vec<f32>,
        world_from_camera: Vec<f32>,
    },
}

/// The model's raw outputs for V views at the model resolution.
#[derive(Debug, Clone, PartialEq)]
pub struct Prediction {
    pub views: usize,
    pub height: usize,
    pub width: usize,
    pub embedding_dim: usize,
    pub depth: Vec<f32>,
    pub gaussians: Vec<f32>,
    pub embeddings: Vec<f32>,
    pub pose_enc: Option<Vec<f32>>,
    /// The instance head's centre votes, where the model has the output (RGB-D).
    pub votes: Option<Votes>,
}

/// Per pixel of a coarser grid, a vote for the centre of the pixel's object, in the model's
/// units (world metres centred on the window's mean camera centre, divided by `points_scale`).
#[derive(Debug, Clone, PartialEq)]
pub struct Votes {
    pub height: usize,
    pub width: usize,
    /// [V,3,height,width], channel-planar per view.
    pub data: Vec<f32>,
}

impl Votes {
    /// The vote of pixel `pixel` (flat over [V,H,W] at the model's resolution `width × height`),
    /// from the vote grid's cell holding it (nearest, as training upsamples it).
    pub fn at(&self, pixel: usize, width: usize, height: usize) -> Option<[f32; 3]> {
        let plane = width * height;
        if plane == 0 {
            return None;
        }
        let (view, i) = (pixel / plane, pixel % plane);
        let (x, y) = (i % width, i / width);
        let (vx, vy) = (x * self.width / width, y * self.height / height);
        let cells = self.width * self.height;
        let base = view * 3 * cells + vy * self.width + vx;
        Some(
            std::array::from_fn(|c| self.data.get(base + c * cells).copied())
                .map(|v| v.unwrap_or(f32::NAN)),
        )
    }

    /// The votes of `pixels` (as [`Self::at`]) in metres: the model's units times `points_scale`
    /// (the centring offset is common to all and drops out of distances); NaN off the grid.
    pub fn of_pixels(
        &self,
        pixels: &[usize],
        width: usize,
        height: usize,
        points_scale: f32,
    ) -> Vec<glam::Vec3> {
        pixels
            .iter()
            .map(|&p| {
                self.at(p, width, height)
                    .map_or(glam::Vec3::NAN, |v| glam::Vec3::from(v) * points_scale)
            })
            .collect()
    }
}

/// A loaded reconstruction model.
pub struct ReconstructionModel {
    session: ort::session::Session,
    pub manifest: Manifest,
}

impl std::fmt::Debug for ReconstructionModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "ReconstructionModel({})", self.manifest.name)
    }
}

/// Bilinear resize of an RGB image to `width × height`, as f32 in [0, 1], channel-planar. (A box
/// filter over each output pixel's footprint, which would average a camera's read noise down, cost
/// 8 points of recall@0.25 and precision on the clean benchmark: the models were trained on
/// point-sampled renders and want their sharpness.)
pub fn resize_rgb_planar(image: &RgbImage, width: usize, height: usize) -> Vec<f32> {
    let (w, h) = (image.width as usize, image.height as usize);
    let mut out = vec![0.0; 3 * width * height];
    let sx = w as f32 / width as f32;
    let sy = h as f32 / height as f32;
    for y in 0..height {
        // Pixel centres map onto pixel centres (align_corners = false).
        let fy = ((y as f32 + 0.5) * sy - 0.5).clamp(0.0, (h - 1) as f32);
        let (y0, wy) = (fy.floor() as usize, fy - fy.floor());
        let y1 = (y0 + 1).min(h - 1);
        for x in 0..width {
            let fx = ((x as f32 + 0.5) * sx - 0.5).clamp(0.0, (w - 1) as f32);
            let (x0, wx) = (fx.floor() as usize, fx - fx.floor());
            let x1 = (x0 + 1).min(w - 1);
            for c in 0..3 {
                let at = |xx: usize, yy: usize| f32::from(image.data[(yy * w + xx) * 3 + c]);
                let top = at(x0, y0) * (1.0 - wx) + at(x1, y0) * wx;
                let bottom = at(x0, y1) * (1.0 - wx) + at(x1, y1) * wx;
                out[c * width * height + y * width + x] = (top * (1.0 - wy) + bottom * wy) / 255.0;
            }
        }
    }
    out
}

/// An image as a model input: resized to `width × height`, channel-planar in [0, 1], then
/// normalised as the manifest says.
pub fn model_image(
    image: &RgbImage,
    width: usize,
    height: usize,
    normalization: Option<&Normalization>,
) -> Vec<f32> {
    let plane = width * height;
    let mut planar = resize_rgb_planar(image, width, height);
    if let Some(n) = normalization {
        for c in 0..3 {
            for v in &mut planar[c * plane..(c + 1) * plane] {
                *v = (*v - n.image_mean[c]) / n.image_std[c];
            }
        }
    }
    planar
}

/// The camera after resizing its image to `width × height` (pinhole scaling, centres kept).
pub fn resized_camera(camera: &Camera, width: usize, height: usize) -> Camera {
    let sx = width as f64 / f64::from(camera.width);
    let sy = height as f64 / f64::from(camera.height);
    Camera {
        width: width as u32,
        height: height as u32,
        fx: camera.fx * sx,
        fy: camera.fy * sy,
        cx: (camera.cx + 0.5) * sx - 0.5,
        cy: (camera.cy + 0.5) * sy - 0.5,
        distortion: camera.distortion,
    }
}

/// Nearest-neighbour resize of depth (depth must not be blended across edges). A median of each
/// footprint's valid measurements was tried instead (it fills single dropped pixels and halves
/// the noise): on the clean benchmark it cost 4 points of recall@0.25 and 6 of precision (a
/// footprint on an edge takes the other side's depth under this pixel's embedding), and on the
/// realistic preset it changed nothing beyond noise. An edge-aware mean (the 3×3 sensor pixels
/// around the sample within 5% of its depth, twice re-centred) was tried too, on benchmark 0-29:
/// for the model's input and lifting, realistic recall@0.25 / @0.5 / precision 65.7 / 44.9 /
/// 74.9% against 66.9 / 40.8 / 77.4%; for lifting only 64.5 / 42.4 / 76.0%; and it cost clean
/// recall@0.5 3 points either way (59.8 -> 56.5 / 56.9%).
fn resize_depth(depth: &DepthImage, width: usize, height: usize) -> Vec<f32> {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let mut out = Vec::with_capacity(width * height);
    for y in 0..height {
        let sy = (((y as f32 + 0.5) * h as f32 / height as f32) as usize).min(h - 1);
        for x in 0..width {
            let sx = (((x as f32 + 0.5) * w as f32 / width as f32) as usize).min(w - 1);
            out.push(depth.metres[sy * w + sx]);
        }
    }
    out
}

/// The sensor depths of the pixels that overlap model pixel `(x, y)` at the model resolution
/// `(width, height)` (among them the one [`resize_depth`] samples).
fn footprint(
    depth: &DepthImage,
    (width, height): (usize, usize),
    (x, y): (usize, usize),
) -> impl Iterator<Item = f32> + '_ {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let span = |i: usize, model: usize, sensor: usize| {
        let start = i * sensor / model;
        let end = ((i + 1) * sensor).div_ceil(model).clamp(start + 1, sensor);
        start..end
    };
    let (rows, columns) = (span(y, height, h), span(x, width, w));
    rows.flat_map(move |sy| columns.clone().map(move |sx| depth.metres[sy * w + sx]))
}

/// Where sensor depth is missing, the model's own depth is trusted when it lies within this
/// fraction of a valid 4-neighbour's sensor depth: the pixel then continues a measured surface.
/// Depth cameras lose the pixels along every depth edge (`--effects realistic`: 8 cm edges), which
/// are an object's outline; not lifting them at all thins every object and takes thin parts
/// (legs, poles) away. On benchmark 0-9 with `--effects realistic` this rule gave recall@0.25 /
/// precision 64.9 / 69.4 % against 59.7 / 66.7 % without it; 2 % gave 61.0 / 66.2, 10 % 62.3 /
/// 68.6, and trusting every such pixel 58.4 / 65.2 (holes' model depth is a guess). Growing the
/// trust further, pixel by pixel from each trusted one, was measured on benchmark 0-29 with
/// `--effects realistic` (recall@0.25 / @0.5 / precision 66.9 / 40.8 / 77.4% for one pixel): 3
/// pixels 66.5 / 39.2 / 77.3, 8 pixels 69.0 / 39.2 / 79.0, 16 pixels 67.8 / 38.4 / 78.3; it
/// found some small tables and bins whose every pixel the camera drops, but boxes got worse.
/// The model's depth only decides; the pixel is lifted at the neighbour's measurement
/// ([`use_sensor_depth`]).
pub const MODEL_DEPTH_AGREEMENT: f32 = 0.05;

/// Replace a prediction's depth by the views' sensor depth at the model resolution (nearest
/// sample, so no depth is averaged across an edge). Where the sensor gave no valid depth (NaN, 0,
/// ∞) and the model's own depth agrees with a valid measurement of the sensor pixels the pixel
/// covers, or else with a valid 4-neighbour's ([`MODEL_DEPTH_AGREEMENT`]), the pixel takes that
/// depth (the closest to the model's, when several agree). The footprint comes first: on
/// benchmark 10-29 with `--effects realistic` it lifts 4% more of the pixels without depth and
/// gave recall@0.25 / @0.5 / precision 69.0 / 45.8 / 84.7% against 68.5 / 44.6 / 83.3% (0-9:
/// 80.5 / 46.8 / 88.6 against 80.5 / 46.8 / 87.3; both within the spread; clean maps unchanged). It
/// continues the measured surface, whose depth the camera knows better than the model (abs-rel
/// 2.6%, most of it at outlines); else the pixel becomes NaN and is not lifted. Lifted at the
/// model's depth instead, benchmark 0-9 with `--effects realistic` scored recall@0.25 / @0.5 /
/// precision 76.6 / 40.3 / 81.9% against 79.2 / 44.2 / 83.6% (mean IoU 0.425 -> 0.444; depth
/// dropout alone 0.506 -> 0.543): outlines spread faces deep and shrank round objects.
/// RGB-D mode: geometry comes from the depth camera, which measures it, and instances from the
/// model's embeddings. Views without depth keep the model's. Returns the pixels lifted at a
/// neighbour's depth.
pub fn use_sensor_depth(prediction: &mut Prediction, views: &[View<'_>]) -> usize {
    let valid = |z: f32| z.is_finite() && z > 0.0;
    let (w, h) = (prediction.width, prediction.height);
    let plane = w * h;
    let mut from_neighbours = 0;
    for (v, view) in views.iter().enumerate().take(prediction.views) {
        let Some(depth) = view.depth else { continue };
        if depth.width == 0 || depth.height == 0 {
            continue;
        }
        let sensor = resize_depth(depth, w, h);
        let out = &mut prediction.depth[v * plane..(v + 1) * plane];
        for (i, &measured) in sensor.iter().enumerate() {
            if valid(measured) {
                out[i] = measured;
                continue;
            }
            let model = out[i];
            if !valid(model) {
                out[i] = f32::NAN;
                continue;
            }
            let (x, y) = (i % w, i / w);
            let agrees = |z: f32| valid(z) && (z - model).abs() <= MODEL_DEPTH_AGREEMENT * z;
            let closest = |a: &f32, b: &f32| (a - model).abs().total_cmp(&(b - model).abs());
            // The pixel's own footprint first: the sensor pixels it covers, beside the one
            // sampled, are the same patch of surface when they agree with the model.
            if let Some(measured) = footprint(depth, (w, h), (x, y))
                .filter(|&z| agrees(z))
                .min_by(closest)
            {
                out[i] = measured;
                from_neighbours += 1;
                continue;
            }
            let agreeing = [
                (x > 0).then(|| i - 1),
                (x + 1 < w).then(|| i + 1),
                (y > 0).then(|| i - w),
                (y + 1 < h).then(|| i + w),
            ]
            .into_iter()
            .flatten()
            .map(|j| sensor[j])
            .filter(|&z| agrees(z))
            .min_by(closest);
            match agreeing {
                Some(measured) => {
                    out[i] = measured;
                    from_neighbours += 1;
                }
                None => out[i] = f32::NAN,
            }
        }
    }
    from_neighbours
}

/// Flat pixel index (view-major, row-major at the model resolution) of every Gaussian that
/// [`ReconstructionModel::to_gaussians`] lifts, in its order: `lift` skips pixels without a finite
/// positive depth.
pub fn lifted_pixels(prediction: &Prediction) -> Vec<usize> {
    prediction
        .depth
        .iter()
        .enumerate()
        .filter(|(_, d)| d.is_finite() && **d > 0.0)
        .map(|(i, _)| i)
        .collect()
}

/// Fill invalid depth (NaN, 0, ∞) for the model's input, as `train/gf/data.py` fills it for
/// training: each pass gives every invalid pixel with a valid 4-neighbour the largest such
/// neighbour (holes at edges belong to the background, which the foreground occludes), until
/// nothing changes. A view without any valid pixel stays as it is. Returns the pixels filled.
/// Only the model's input: a filled pixel is never lifted (see [`use_sensor_depth`]).
pub fn fill_invalid_depth(metres: &mut [f32], width: usize, height: usize) -> usize {
    let valid = |z: f32| z.is_finite() && z > 0.0;
    if width * height != metres.len() {
        return 0;
    }
    let (mut filled, mut before) = (0, metres.to_vec());
    loop {
        before.copy_from_slice(metres);
        let mut changed = 0;
        for y in 0..height {
            for x in 0..width {
                let i = y * width + x;
                if valid(before[i]) {
                    continue;
                }
                let neighbours = [
                    (x > 0).then(|| i - 1),
                    (x + 1 < width).then(|| i + 1),
                    (y > 0).then(|| i - width),
                    (y + 1 < height).then(|| i + width),
                ];
                let best = neighbours
                    .into_iter()
                    .flatten()
                    .map(|j| before[j])
                    .filter(|&z| valid(z))
                    .fold(f32::NAN, f32::max);
                if valid(best) {
                    metres[i] = best;
                    changed += 1;
                }
            }
        }
        if changed == 0 {
            return filled;
        }
        filled += changed;
    }
}

/// RGB-D mode's `points`: every pixel's world point from sensor depth, centred and scaled.
fn world_points(
    views: &[View<'_>],
    width: usize,
    height: usize,
    centre: DVec3,
    scale: f64,
) -> Result<Vec<f32>> {
    let plane = width * height;
    let mut points = Vec::with_capacity(views.len() * 3 * plane);
    for view in views {
        let depth = view.depth.ok_or_else(|| {
            ModelError::Input("an RGB-D model needs a depth image for every view".into())
        })?;
        let camera = resized_camera(&view.camera, width, height);
        let mut metres = resize_depth(depth, width, height);
        fill_invalid_depth(&mut metres, width, height);
        let mut planar = vec![0.0f32; 3 * plane];
        for y in 0..height {
            for x in 0..width {
                let d = metres[y * width + x];
                // Only a view without any valid depth is left: the centre (0 after centring).
                let world = if d.is_finite() && d > 0.0 {
                    let p = camera.unproject(DVec2::new(x as f64, y as f64), f64::from(d));
                    view.world_from_camera.transform_point(p)
                } else {
                    centre
                };
                let n = (world - centre) / scale;
                for (c, value) in [n.x, n.y, n.z].into_iter().enumerate() {
                    planar[c * plane + y * width + x] = value as f32;
                }
            }
        }
        points.extend(planar);
    }
    Ok(points)
}

/// Posed RGB mode's `intrinsics` (the pinhole at the model resolution; the model's plane sweep
/// ignores lens distortion) and `world_from_camera` (rotation as is, translation centred and scaled
/// like the points), row-major.
fn posed_cameras(
    views: &[View<'_>],
    width: usize,
    height: usize,
    centre: DVec3,
    scale: f64,
) -> Geometry {
    let mut intrinsics = Vec::with_capacity(views.len() * 9);
    let mut world_from_camera = Vec::with_capacity(views.len() * 16);
    for view in views {
        let c = resized_camera(&view.camera, width, height);
        intrinsics.extend([c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0].map(|v| v as f32));
        let rotation = DMat3::from_quat(view.world_from_camera.rotation);
        let t = (view.world_from_camera.translation - centre) / scale;
        for (row, translation) in [t.x, t.y, t.z].into_iter().enumerate() {
            let r = rotation.row(row);
            world_from_camera.extend([r.x, r.y, r.z, translation].map(|v| v as f32));
        }
        world_from_camera.extend([0.0, 0.0, 0.0, 1.0]);
    }
    Geometry::Cameras {
        intrinsics,
        world_from_camera,
    }
}

impl ReconstructionModel {
    /// Load the model a manifest describes and check the graph against the manifest.
    pub fn load(manifest_path: &Path, options: &SessionOptions) -> Result<Self> {
        let manifest = Manifest::load(manifest_path)?;
        if manifest.kind != ModelKind::Reconstruction {
            return Err(ModelError::Manifest {
                path: manifest_path.to_owned(),
                reason: format!("kind is {:?}, not reconstruction", manifest.kind),
            });
        }
        let session = open_session(&manifest.model_path(), options)?;
        manifest.check(&session)?;
        Ok(Self { session, manifest })
    }

    /// What world metres were divided by for the model's geometry input and outputs (1 when
    /// the manifest gives no normalisation).
    pub fn points_scale(&self) -> f32 {
        self.manifest
            .normalization
            .as_ref()
            .map_or(1.0, |n| n.points_scale)
    }

    pub fn mode(&self) -> InputMode {
        self.manifest.mode.unwrap_or(InputMode::Rgb)
    }

    /// Model input size: the manifest's, else the first view's.
    fn input_size(&self, first: &View<'_>) -> (usize, usize) {
        (
            self.manifest
                .input_width
                .unwrap_or(first.rgb.width as usize),
            self.manifest
                .input_height
                .unwrap_or(first.rgb.height as usize),
        )
    }

    /// Build the input tensors for `views` at the model resolution, as the model's mode asks.
    pub fn preprocess(&self, views: &[View<'_>]) -> Result<ModelInputs> {
        let Some(first) = views.first() else {
            return Err(ModelError::Input("no views".into()));
        };
        let (width, height) = self.input_size(first);
        let plane = width * height;
        let norm = self.manifest.normalization.clone();
        let mut images = Vec::with_capacity(views.len() * 3 * plane);
        for view in views {
            if view.rgb.data.len() != (view.rgb.width * view.rgb.height * 3) as usize
                || view.rgb.width == 0
            {
                return Err(ModelError::Input(
                    "colour image size does not match its data".into(),
                ));
            }
            images.extend(model_image(view.rgb, width, height, norm.as_ref()));
        }
        // World geometry is centred on the mean camera centre so the window's gauge is
        // translation-free, then scaled as the model was trained.
        let centre = views
            .iter()
            .map(|v| v.world_from_camera.translation)
            .sum::<DVec3>()
            / views.len() as f64;
        let scale = f64::from(self.points_scale());
        let geometry = match self.mode() {
            InputMode::Rgb => Geometry::None,
            InputMode::RgbPosed => posed_cameras(views, width, height, centre, scale),
            InputMode::Rgbd => Geometry::Points(world_points(views, width, height, centre, scale)?),
        };
        Ok(ModelInputs {
            views: views.len(),
            height,
            width,
            images,
            geometry,
        })
    }
    /// Run the model on already-built input tensors.
    pub fn run_tensors(&mut self, inputs: ModelInputs) -> Result<Prediction> {
        let ModelInputs {
            views,
            height,
            width,
            images,
            geometry,
        } = inputs;
        let shape = [1usize, views, 3, height, width];
        let images = ort::value::Tensor::from_array((shape, images))?;
        let outputs = match geometry {
            Geometry::None => self.session.run(ort::inputs!["images" => images])?,
            Geometry::Points(points) => {
                let points = ort::value::Tensor::from_array((shape, points))?;
                self.session
                    .run(ort::inputs!["images" => images, "points" => points])?
            }
            Geometry::Cameras {
                intrinsics,
                world_from_camera,
            } => {
                let intrinsics =
                    ort::value::Tensor::from_array(([1usize, views, 3, 3], intrinsics))?;
                let world_from_camera =
                    ort::value::Tensor::from_array(([1usize, views, 4, 4], world_from_camera))?;
                self.session.run(ort::inputs![
                    "images" => images,
                    "intrinsics" => intrinsics,
                    "world_from_camera" => world_from_camera
                ])?
            }
        };
        let extract = |name: &str, channels: Option<usize>| -> Result<Vec<f32>> {
            let value = outputs
                .get(name)
                .ok_or_else(|| ModelError::Ort(format!("output `{name}` missing")))?;
            let (out_shape, data) = value.try_extract_tensor::<f32>()?;
            let dims: Vec<i64> = out_shape.iter().copied().collect();
            let expected: Vec<i64> = match channels {
                Some(c) => vec![1, views as i64, c as i64, height as i64, width as i64],
                None => vec![1, views as i64, height as i64, width as i64],
            };
            if dims != expected {
                return Err(ModelError::ContractMismatch {
                    model: name.to_owned(),
                    problems: vec![format!(
                        "output `{name}` has shape {dims:?}, expected {expected:?}"
                    )],
                });
            }
            if let Some(i) = data.iter().position(|v| !v.is_finite()) {
                return Err(ModelError::Ort(format!(
                    "output `{name}` has a non-finite value at {i}"
                )));
            }
            Ok(data.to_vec())
        };
        let embedding_dim = self.manifest.embedding_dim.unwrap_or(8);
        let depth = extract("depth", None)?;
        let gaussians = extract("gaussians", Some(GAUSSIAN_CHANNELS))?;
        let embeddings = extract("embeddings", Some(embedding_dim))?;
        let pose_enc = match outputs.get("pose_enc") {
            Some(value) => Some(value.try_extract_tensor::<f32>()?.1.to_vec()),
            None => None,
        };
        let votes = match outputs.get("votes") {
            Some(value) => {
                let (shape, data) = value.try_extract_tensor::<f32>()?;
                let dims: Vec<i64> = shape.iter().copied().collect();
                match dims[..] {
                    [1, v, 3, h, w] if v == views as i64 && h > 0 && w > 0 => Some(Votes {
                        height: h as usize,
                        width: w as usize,
                        data: data.to_vec(),
                    }),
                    _ => {
                        return Err(ModelError::ContractMismatch {
                            model: "votes".to_owned(),
                            problems: vec![format!(
                                "output `votes` has shape {dims:?}, expected [1, {views}, 3, h, w]"
                            )],
                        })
                    }
                }
            }
            None => None,
        };
        Ok(Prediction {
            views,
            height,
            width,
            embedding_dim,
            depth,
            gaussians,
            embeddings,
            pose_enc,
            votes,
        })
    }

    /// Pre-process, run, and return the raw prediction.
    pub fn predict(&mut self, views: &[View<'_>]) -> Result<Prediction> {
        let inputs = self.preprocess(views)?;
        self.run_tensors(inputs)
    }

    /// Lift a prediction to world-space Gaussians with the views' cameras and poses. Colours are
    /// the resized input colour plus the predicted residual.
    pub fn to_gaussians(&self, prediction: &Prediction, views: &[View<'_>]) -> Result<Gaussians> {
        let (w, h) = (prediction.width, prediction.height);
        let plane = w * h;
        let d_e = prediction.embedding_dim;
        let mut all = Gaussians::with_dims(d_e, 0);
        for (v, view) in views.iter().enumerate().take(prediction.views) {
            let g = &prediction.gaussians
                [v * GAUSSIAN_CHANNELS * plane..(v + 1) * GAUSSIAN_CHANNELS * plane];
            let channel = |c: usize, i: usize| g[c * plane + i];
            let rgb = resize_rgb_planar(view.rgb, w, h);
            let opacity: Vec<f32> = (0..plane).map(|i| channel(0, i).clamp(0.0, 1.0)).collect();
            let scale: Vec<[f32; 3]> = (0..plane)
                .map(|i| [channel(1, i), channel(2, i), channel(3, i)])
                .collect();
            let rotation: Vec<[f32; 4]> = (0..plane)
                .map(|i| [channel(4, i), channel(5, i), channel(6, i), channel(7, i)])
                .collect();
            let color: Vec<[f32; 3]> = (0..plane)
                .map(|i| {
                    std::array::from_fn(|c| {
                        (rgb[c * plane + i] + channel(8 + c, i)).clamp(0.0, 1.0)
                    })
                })
                .collect();
            let e = &prediction.embeddings[v * d_e * plane..(v + 1) * d_e * plane];
            let embedding: Vec<f32> = (0..plane)
                .flat_map(|i| (0..d_e).map(move |k| e[k * plane + i]))
                .collect();
            let view_prediction = PixelAligned {
                width: w,
                height: h,
                depth: &prediction.depth[v * plane..(v + 1) * plane],
                opacity: &opacity,
                scale: &scale,
                rotation: &rotation,
                color: &color,
                embedding_dim: d_e,
                embedding: &embedding,
            };
            let camera = resized_camera(&view.camera, w, h);
            let lifted = lift(&view_prediction, &camera, &view.world_from_camera)
                .map_err(|e| ModelError::Input(e.to_string()))?;
            all.extend(&lifted);
        }
        Ok(all)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;

    #[test]
    fn dataset_resampling_matches_the_node() {
        // `sim dataset --sensor` resamples sensor views for training; it must feed the model what
        // this module feeds it from the same camera image.
        let (w, h) = (37usize, 23usize);
        let data: Vec<u8> = (0..w * h * 3)
            .map(|i| ((i * 97 + i / 7) % 256) as u8)
            .collect();
        let metres: Vec<f32> = (0..w * h)
            .map(|i| {
                if i % 11 == 0 {
                    f32::NAN
                } else {
                    0.5 + i as f32 * 1e-3
                }
            })
            .collect();
        let (mw, mh) = (16usize, 9usize);
        let node_rgb = resize_rgb_planar(
            &RgbImage {
                width: w as u32,
                height: h as u32,
                data: data.clone(),
            },
            mw,
            mh,
        );
        let sim_rgb = groupforward_sim::resample::bilinear_rgb(&data, (w, h), (mw, mh));
        for (i, byte) in sim_rgb.iter().enumerate() {
            let (pixel, c) = (i / 3, i % 3);
            let node = node_rgb[c * mw * mh + pixel] * 255.0;
            assert!(
                (node - f32::from(*byte)).abs() <= 0.5 + 1e-3,
                "pixel {pixel} channel {c}"
            );
        }
        let depth = DepthImage {
            width: w as u32,
            height: h as u32,
            metres: metres.clone(),
        };
        let node_depth = resize_depth(&depth, mw, mh);
        let sim_depth = groupforward_sim::resample::nearest(&metres, (w, h), (mw, mh));
        assert_eq!(node_depth.len(), sim_depth.len());
        for (a, b) in node_depth.iter().zip(&sim_depth) {
            assert!(a.to_bits() == b.to_bits());
        }
        let camera = Camera::pinhole(w as u32, h as u32, 30.0, 31.0, 18.2, 11.7).unwrap();
        let node_camera = resized_camera(&camera, mw, mh);
        let sim_camera = groupforward_sim::resample::resized_pinhole(
            &groupforward_sim::render::Pinhole {
                width: w as u32,
                height: h as u32,
                fx: 30.0,
                fy: 31.0,
                cx: 18.2,
                cy: 11.7,
            },
            mw as u32,
            mh as u32,
        );
        for (a, b) in [
            (node_camera.fx, sim_camera.fx),
            (node_camera.fy, sim_camera.fy),
            (node_camera.cx, sim_camera.cx),
            (node_camera.cy, sim_camera.cy),
        ] {
            assert!((a - b).abs() < 1e-12);
        }
    }

    #[test]
    fn posed_cameras_put_each_pixel_where_the_points_do() {
        // Two views at 320×240 for a 128×96 model, turned and apart; what the posed model is given
        // (intrinsics, pose) must place a pixel at depth d exactly where the RGB-D points put it.
        let rgb = RgbImage {
            width: 320,
            height: 240,
            data: vec![0; 320 * 240 * 3],
        };
        let depth = DepthImage {
            width: 320,
            height: 240,
            metres: vec![2.5; 320 * 240],
        };
        let camera = Camera::pinhole(320, 240, 160.0, 150.0, 161.0, 118.0).unwrap();
        let poses = [
            Rigid::new(DQuat::from_rotation_y(0.3), DVec3::new(1.0, 0.2, -0.5)),
            Rigid::new(
                DQuat::from_euler(glam::EulerRot::XYZ, -0.2, 0.5, 0.1),
                DVec3::new(1.4, 0.1, -0.3),
            ),
        ];
        let views: Vec<View> = poses
            .iter()
            .map(|pose| View {
                rgb: &rgb,
                depth: Some(&depth),
                camera,
                world_from_camera: *pose,
            })
            .collect();
        let (width, height, scale) = (128, 96, 3.0);
        let centre = (poses[0].translation + poses[1].translation) / 2.0;
        let points = world_points(&views, width, height, centre, scale).unwrap();
        let Geometry::Cameras {
            intrinsics,
            world_from_camera,
        } = posed_cameras(&views, width, height, centre, scale)
        else {
            panic!("posed cameras")
        };
        assert_eq!((intrinsics.len(), world_from_camera.len()), (18, 32));
        let plane = width * height;
        for v in 0..2 {
            let k = &intrinsics[v * 9..(v + 1) * 9];
            let m = &world_from_camera[v * 16..(v + 1) * 16];
            assert_eq!(&m[12..], &[0.0, 0.0, 0.0, 1.0]);
            for (x, y) in [(0usize, 0usize), (63, 47), (127, 95), (100, 10)] {
                let d = 2.5f32;
                let ray = [(x as f32 - k[2]) / k[0], (y as f32 - k[5]) / k[4], 1.0];
                for row in 0..3 {
                    let r = &m[row * 4..row * 4 + 4];
                    // Rotation and translation are in world units of `scale` metres.
                    let from_pose =
                        (r[0] * ray[0] + r[1] * ray[1] + r[2] * ray[2]) * d / scale as f32 + r[3];
                    let from_points = points[v * 3 * plane + row * plane + y * width + x];
                    assert!(
                        (from_pose - from_points).abs() < 1e-5,
                        "view {v} pixel ({x},{y}) axis {row}: {from_pose} vs {from_points}"
                    );
                }
            }
        }
    }

    /// `sensor` (one view, `width` × `height`) applied to a prediction of depth `model`: the
    /// depth lifted and the pixels lifted at a neighbour's depth.
    fn with_sensor_depth(sensor: Vec<f32>, model: Vec<f32>, width: usize) -> (Vec<f32>, usize) {
        with_sensor_depth_of_width(sensor, width, model, width)
    }

    /// [`with_sensor_depth`] with a sensor `sensor_width` pixels wide (its rows scaled alike).
    fn with_sensor_depth_of_width(
        sensor: Vec<f32>,
        sensor_width: usize,
        model: Vec<f32>,
        width: usize,
    ) -> (Vec<f32>, usize) {
        let height = model.len() / width;
        let rgb = RgbImage {
            width: width as u32,
            height: height as u32,
            data: vec![0; width * height * 3],
        };
        let depth = DepthImage {
            width: sensor_width as u32,
            height: (sensor.len() / sensor_width) as u32,
            metres: sensor,
        };
        let camera = Camera::pinhole(width as u32, height as u32, 10.0, 10.0, 1.0, 1.0).unwrap();
        let view = View {
            rgb: &rgb,
            depth: Some(&depth),
            camera,
            world_from_camera: Rigid::new(DQuat::IDENTITY, DVec3::ZERO),
        };
        let mut prediction = Prediction {
            views: 1,
            height,
            width,
            embedding_dim: 0,
            depth: model,
            gaussians: Vec::new(),
            embeddings: Vec::new(),
            pose_enc: None,
            votes: None,
        };
        let from_neighbours = use_sensor_depth(&mut prediction, &[view]);
        (prediction.depth, from_neighbours)
    }

    #[test]
    fn a_hole_is_lifted_only_next_to_a_measurement_the_models_depth_agrees_with_at_its_depth() {
        // Row 0: a measurement at x = 0, then holes where the model continues the surface (1 cm
        // per pixel), then guesses 3.5 m. Row 1 (1 m): a hole between two measurements and a run
        // after them where the model guesses far off.
        let width = 6;
        let nan = f32::NAN;
        let mut sensor = vec![nan; 2 * width];
        sensor[0] = 2.0;
        sensor[width] = 1.0;
        sensor[width + 2] = 1.0;
        let mut model: Vec<f32> = (0..width).map(|x| 2.0 + 0.01 * x as f32).collect();
        model[width - 1] = 3.5;
        model.extend((0..width).map(|x| if x == 1 { 1.6 } else { 1.5 }));
        let (out, from_neighbours) = with_sensor_depth(sensor, model, width);
        assert_eq!(from_neighbours, 1);
        // Measurements replace the model's depth.
        assert_eq!((out[0], out[width], out[width + 2]), (2.0, 1.0, 1.0));
        assert_eq!(
            out[1], 2.0,
            "continues the measurement beside it, at its depth"
        );
        assert!(
            out[2..width].iter().all(|z| z.is_nan()),
            "no measurement beside them, or a guess: {:?}",
            &out[2..width]
        );
        assert!(
            out[width + 1].is_nan(),
            "a hole's guess 0.6 m off is not lifted"
        );
        assert!(out[width + 3..].iter().all(|z| z.is_nan()));

        // An outline between a face at 3.0 m and a wall 10 cm behind it, the model's depth
        // between them and within 5% of both: the hole takes the nearer one's depth.
        let (out, from_neighbours) =
            with_sensor_depth(vec![3.0, nan, 3.1], vec![0.0, 3.04, 0.0], 3);
        assert_eq!((out[1], from_neighbours), (3.0, 1));
        let (out, _) = with_sensor_depth(vec![3.0, nan, 3.1], vec![0.0, 3.07, 0.0], 3);
        assert_eq!(out[1], 3.1);
    }

    #[test]
    fn a_hole_takes_an_agreeing_measurement_from_its_own_footprint_on_a_finer_sensor() {
        // A 4×4 sensor under a 2×2 prediction: each model pixel covers 2×2 sensor pixels and
        // samples the lower right one. A wall at 5 m; the top left footprint holds one
        // measurement of a face at 2 m beside three holes, the sampled one among them.
        let nan = f32::NAN;
        let mut sensor = vec![5.0f32; 16];
        for i in [1, 4, 5] {
            sensor[i] = nan;
        }
        sensor[0] = 2.0;
        // The bottom left pixel samples a hole too, with only the wall around it.
        sensor[13] = nan;
        let model = vec![2.05, 5.0, 2.0, 5.0];
        let (out, from_neighbours) = with_sensor_depth_of_width(sensor, 4, model, 2);
        assert_eq!(out[0], 2.0, "the face measured beside the sampled hole");
        assert_eq!((out[1], out[3]), (5.0, 5.0));
        assert!(out[2].is_nan(), "the wall around it is 3 m off the model");
        assert_eq!(from_neighbours, 1);
    }

    #[test]
    fn invalid_depth_is_filled_from_the_farthest_valid_neighbour_until_none_is_left() {
        let nan = f32::NAN;
        // A 1 m object in front of a 3 m wall, with a hole on the edge and one in the wall.
        let mut depth = vec![
            1.0, nan, 3.0, 3.0, //
            1.0, 1.0, nan, 3.0, //
            nan, nan, nan, 0.0, //
        ];
        let filled = fill_invalid_depth(&mut depth, 4, 3);
        assert_eq!(filled, 6);
        assert_eq!(
            depth,
            [
                1.0, 3.0, 3.0, 3.0, //
                1.0, 1.0, 3.0, 3.0, //
                1.0, 1.0, 3.0, 3.0, //
            ]
        );
        // Nothing to fill from: left as it is.
        let mut empty = vec![nan, 0.0, f32::INFINITY];
        assert_eq!(fill_invalid_depth(&mut empty, 3, 1), 0);
        assert!(empty[0].is_nan() && empty[1] == 0.0);
        // A clean image is untouched.
        let mut clean = vec![2.0; 6];
        assert_eq!(fill_invalid_depth(&mut clean, 3, 2), 0);
    }

    #[test]
    fn resizing_preserves_constant_images_and_camera_geometry() {
        let image = RgbImage {
            width: 8,
            height: 6,
            data: vec![51; 8 * 6 * 3],
        };
        let planar = resize_rgb_planar(&image, 5, 3);
        assert!(planar.iter().all(|v| (v - 0.2).abs() < 1e-6));
        let camera = Camera::pinhole(640, 480, 500.0, 500.0, 319.5, 239.5).unwrap();
        let half = resized_camera(&camera, 320, 240);
        assert!((half.fx - 250.0).abs() < 1e-9 && (half.cx - 159.5).abs() < 1e-9);
        // The same ray through corresponding pixel centres.
        let a = camera.ray(DVec2::new(100.0 * 2.0 + 0.5, 50.0 * 2.0 + 0.5));
        let b = half.ray(DVec2::new(100.0, 50.0));
        assert!((a - b).length() < 1e-9);
    }
}
