//! The evidence bundle a reasoner sees (ARCHITECTURE.md §2): per candidate the structured node as JSON
//! (names, centre, extent, volume, colour, visibility, its nearest neighbours), and images: a
//! global overview with the candidates' outlines numbered (the current choice drawn heavier) on
//! the camera's newest picture, per candidate its mask highlighted, an object-centred crop and
//! its local context from the camera's pictures of it ([`crate::observations`]). Where the node
//! kept no picture (a map loaded from disk, an instance never seen well), the map is rendered
//! with the rasterizer at the newest keyframe instead. Written as PNG + JSON by `--evidence DIR`
//! so a person can look at what the reasoner saw.

use std::path::Path;

use glam::DVec2;
use groupforward_relations::color_name;
use serde_json::json;

use super::scene::ReferScene;
use super::Answer;
use crate::frame::{Keyframe, RgbImage};
use crate::model::reconstruction::resized_camera;
use crate::recon::gaussians::Gaussians;
use crate::recon::raster::{render, RasterSettings};

/// Evidence images are rendered this many times the keyframe's (model) resolution.
pub const EVIDENCE_SCALE: usize = 3;

/// Outline colours of candidates 1, 2, ... (cycled).
const PALETTE: [[u8; 3]; 8] = [
    [230, 25, 75],
    [60, 180, 75],
    [255, 225, 25],
    [0, 130, 200],
    [245, 130, 48],
    [145, 30, 180],
    [70, 240, 240],
    [240, 50, 230],
];

/// What a reasoner is shown.
#[derive(Debug, Clone, PartialEq)]
pub struct Evidence {
    pub json: serde_json::Value,
    /// (name, image): `overview` first, then `candidate_<n>` (highlights), then
    /// `candidate_<n>_crop` and `candidate_<n>_context`.
    pub images: Vec<(String, RgbImage)>,
}

/// The structured part: the expression, its parse, and per candidate (numbered from 1 as in
/// the images) its node and nearest neighbours.
pub fn structured(scene: &ReferScene, answer: &Answer) -> serde_json::Value {
    let candidates: Vec<serde_json::Value> = answer
        .candidates
        .iter()
        .enumerate()
        .map(|(k, c)| {
            let node = &scene.nodes[c.index];
            let mut names: Vec<(usize, f32)> = node.names.iter().copied().enumerate().collect();
            names.sort_by(|a, b| b.1.total_cmp(&a.1));
            let centre = node.center();
            let mut neighbours: Vec<(f64, &super::ReferNode)> = scene
                .nodes
                .iter()
                .filter(|n| n.id != node.id)
                .map(|n| ((n.center() - centre).length(), n))
                .collect();
            neighbours.sort_by(|a, b| a.0.total_cmp(&b.0));
            let size = node.hi - node.lo;
            json!({
                "number": k + 1,
                "id": node.id,
                "names": names.iter().take(3).map(|(i, p)| json!({"name": scene.phrases[*i], "p": p})).collect::<Vec<_>>(),
                "centre_m": [centre.x, centre.y, centre.z],
                "size_m": [size.x, size.y, size.z],
                "volume_m3": size.x * size.y * size.z,
                "colour": color_name(node.color),
                "visibility": node.visibility,
                // One window saw it; the map has not confirmed it (ReferNode::tentative).
                "tentative": node.tentative,
                "scores": {"semantic": c.semantic, "geometric": c.geometric, "visibility": c.visibility, "combined": c.score},
                "neighbours": neighbours.iter().take(3).map(|(d, n)| json!({
                    "id": n.id, "name": n.label, "distance_m": d,
                    "height_difference_m": n.center().z - centre.z})).collect::<Vec<_>>(),
            })
        })
        .collect();
    json!({
        "expression": answer.query.text,
        "parse": answer.query,
        "candidates": candidates,
        "builtin_choice": answer.chosen.iter().map(|c| scene.nodes[c.index].id.clone()).collect::<Vec<_>>(),
    })
}

/// The bundle: the structured part, and images rendered from `gaussians` (the map's instances
/// by id, all of them, for the overview) at the newest keyframe; at most `max_images` images.
pub fn build(
    scene: &ReferScene,
    answer: &Answer,
    gaussians: &[(String, Gaussians)],
    max_images: usize,
) -> Evidence {
    let json = structured(scene, answer);
    let images = scene
        .keyframes
        .first()
        .map(|kf| images(scene, answer, gaussians, kf, max_images))
        .unwrap_or_default();
    Evidence { json, images }
}

fn images(
    scene: &ReferScene,
    answer: &Answer,
    gaussians: &[(String, Gaussians)],
    keyframe: &Keyframe,
    max_images: usize,
) -> Vec<(String, RgbImage)> {
    if max_images == 0 {
        return Vec::new();
    }
    let camera = resized_camera(
        &keyframe.camera,
        keyframe.camera.width as usize * EVIDENCE_SCALE,
        keyframe.camera.height as usize * EVIDENCE_SCALE,
    );
    let view = Keyframe {
        camera,
        ..keyframe.clone()
    };
    let observed = |k: usize| {
        let id = &scene.nodes[answer.candidates[k].index].id;
        scene.observations.of(id).first().cloned()
    };
    let picture = scene.observations.newest();
    // The map is rendered only where a picture is missing: for the overview without the
    // camera's newest picture, or for a candidate the camera's pictures do not show.
    let rendered =
        if picture.is_none() || (0..answer.candidates.len()).any(|k| observed(k).is_none()) {
            let Some(rendered) = map_render(scene, answer, gaussians, &view) else {
                return Vec::new();
            };
            Some(rendered)
        } else {
            None
        };
    let overview = match (picture, &rendered) {
        (Some(picture), _) => outlined(scene, answer, &picture.image, &picture.keyframe),
        (None, Some((base, _))) => outlined(scene, answer, base, &view),
        (None, None) => return Vec::new(),
    };
    let mut out = vec![("overview".to_owned(), overview)];
    for k in 0..answer.candidates.len() {
        if out.len() >= max_images {
            break;
        }
        // Where the camera's own picture of it was kept, that is what the reasoner sees;
        // otherwise its visible pixels in the render.
        let colour = PALETTE[k % PALETTE.len()];
        let image = match (observed(k), &rendered) {
            (Some(o), _) => highlighted(&o.image, &o.mask, colour),
            (None, Some((base, owner))) => {
                let mask: Vec<bool> = owner.iter().map(|o| *o == k + 1).collect();
                highlighted(base, &mask, colour)
            }
            (None, None) => continue,
        };
        out.push((format!("candidate_{}", k + 1), image));
    }
    // Then per candidate an object-centred crop and its local context (three times the box).
    for (scale, name) in [(1.2, "crop"), (3.0, "context")] {
        for (k, c) in answer.candidates.iter().enumerate() {
            if out.len() >= max_images {
                break;
            }
            if let Some(o) = observed(k) {
                let image = match name {
                    "crop" => mask_crop(&o.image, &o.mask, scale),
                    _ => Some(o.image.clone()),
                };
                if let Some(image) = image {
                    out.push((format!("candidate_{}_{name}", k + 1), image));
                }
                continue;
            }
            let projected = projected_box(&scene.nodes[c.index], &view);
            if let (Some((lo, hi)), Some((base, _))) = (projected, &rendered) {
                let centre = (lo + hi) / 2.0;
                let half = (hi - lo) * scale / 2.0;
                if let Some(image) = crop(base, centre - half, centre + half) {
                    out.push((format!("candidate_{}_{name}", k + 1), image));
                }
            }
        }
    }
    out.truncate(max_images);
    out
}

/// One render of the whole map (`gaussians`, by id) at `view` with an owner channel: its colour
/// image, and per pixel 1 + the candidate in front there (0: none).
fn map_render(
    scene: &ReferScene,
    answer: &Answer,
    gaussians: &[(String, Gaussians)],
    view: &Keyframe,
) -> Option<(RgbImage, Vec<usize>)> {
    let mut all = Gaussians::with_dims(0, 0);
    let mut features = Vec::new();
    let candidate_of = |id: &str| {
        answer
            .candidates
            .iter()
            .position(|c| scene.nodes[c.index].id == id)
    };
    // Colour, then one channel per candidate: a pixel is a candidate's where its channel carries
    // most of the alpha (a single blended owner number would mislabel edges between instances).
    let k_count = answer.candidates.len();
    let channels = 3 + k_count;
    for (id, g) in gaussians {
        let owner = candidate_of(id);
        all.extend_geometry(g);
        for c in &g.colors {
            features.extend_from_slice(&[c.x, c.y, c.z]);
            features.extend((0..k_count).map(|k| if owner == Some(k) { 1.0 } else { 0.0 }));
        }
    }
    let r = render(
        &all,
        &features,
        channels,
        &view.camera,
        &view.world_from_camera.inverse(),
        &RasterSettings::default(),
    )
    .ok()?;
    let (w, h) = (r.width, r.height);
    let pixels = w * h;
    let mut base = vec![0u8; pixels * 3];
    let mut owner = vec![0usize; pixels];
    for p in 0..pixels {
        let f = &r.features[p * channels..(p + 1) * channels];
        for c in 0..3 {
            base[p * 3 + c] = ((f[c] / r.alpha[p].max(1.0)).clamp(0.0, 1.0) * 255.0) as u8;
        }
        owner[p] = f[3..]
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .filter(|(_, v)| **v > 0.5)
            .map_or(0, |(k, _)| k + 1);
    }
    let base = RgbImage {
        width: w as u32,
        height: h as u32,
        data: base,
    };
    Some((base, owner))
}

/// `image` (seen from `view`) with the candidates' boxes outlined and numbered, the reasoner's
/// choice drawn heavier: the overview shows the answer at a glance.
fn outlined(scene: &ReferScene, answer: &Answer, image: &RgbImage, view: &Keyframe) -> RgbImage {
    let mut overview = image.clone();
    for (k, c) in answer.candidates.iter().enumerate() {
        let node = &scene.nodes[c.index];
        if let Some((lo, hi)) = projected_box(node, view) {
            let colour = PALETTE[k % PALETTE.len()];
            let chosen = answer.chosen.iter().any(|ch| ch.index == c.index);
            draw_rect(&mut overview, lo, hi, colour, if chosen { 5 } else { 2 });
            draw_number(
                &mut overview,
                lo.x as i64 + 2,
                lo.y as i64 + 2,
                k + 1,
                colour,
            );
        }
    }
    overview
}

/// `image` with the `mask`ed pixels tinted by `colour` and the rest dimmed.
fn highlighted(image: &RgbImage, mask: &[bool], colour: [u8; 3]) -> RgbImage {
    let mut data = image.data.clone();
    for (p, pixel) in data.chunks_exact_mut(3).enumerate() {
        let mine = mask.get(p).copied().unwrap_or(false);
        for (v, tint) in pixel.iter_mut().zip(colour) {
            *v = if mine {
                (0.4 * f32::from(*v) + 0.6 * f32::from(tint)) as u8
            } else {
                (0.35 * f32::from(*v)) as u8
            };
        }
    }
    RgbImage { data, ..*image }
}

/// The part of `image` around its `mask`ed pixels, their extent times `scale`; None without any.
fn mask_crop(image: &RgbImage, mask: &[bool], scale: f64) -> Option<RgbImage> {
    let w = image.width as usize;
    let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
    for (p, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        let at = DVec2::new((p % w.max(1)) as f64, (p / w.max(1)) as f64);
        lo = lo.min(at);
        hi = hi.max(at + DVec2::ONE);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        return None;
    }
    let (centre, half) = ((lo + hi) / 2.0, (hi - lo) * scale / 2.0);
    crop(image, centre - half, centre + half)
}

/// The part of `image` inside [lo, hi] (clamped); None when that is empty.
fn crop(image: &RgbImage, lo: DVec2, hi: DVec2) -> Option<RgbImage> {
    let (w, h) = (f64::from(image.width), f64::from(image.height));
    let x0 = lo.x.clamp(0.0, w) as usize;
    let y0 = lo.y.clamp(0.0, h) as usize;
    let x1 = hi.x.clamp(0.0, w).ceil() as usize;
    let y1 = hi.y.clamp(0.0, h).ceil() as usize;
    if x1 <= x0 || y1 <= y0 {
        return None;
    }
    let stride = image.width as usize * 3;
    let mut data = Vec::with_capacity((x1 - x0) * (y1 - y0) * 3);
    for y in y0..y1 {
        data.extend_from_slice(&image.data[y * stride + x0 * 3..y * stride + x1 * 3]);
    }
    Some(RgbImage {
        width: (x1 - x0) as u32,
        height: (y1 - y0) as u32,
        data,
    })
}

/// The image rectangle of a node's box corners in `view` (None: behind the camera or outside).
fn projected_box(node: &super::ReferNode, view: &Keyframe) -> Option<(DVec2, DVec2)> {
    let camera_from_world = view.world_from_camera.inverse();
    let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
    for i in 0..8 {
        let corner = glam::DVec3::new(
            if i & 1 == 0 { node.lo.x } else { node.hi.x },
            if i & 2 == 0 { node.lo.y } else { node.hi.y },
            if i & 4 == 0 { node.lo.z } else { node.hi.z },
        );
        let p = view
            .camera
            .project(camera_from_world.transform_point(corner))?;
        lo = lo.min(p);
        hi = hi.max(p);
    }
    let (w, h) = (f64::from(view.camera.width), f64::from(view.camera.height));
    let lo = lo.max(DVec2::ZERO);
    let hi = hi.min(DVec2::new(w - 1.0, h - 1.0));
    (lo.x < hi.x && lo.y < hi.y).then_some((lo, hi))
}

fn put(image: &mut RgbImage, x: i64, y: i64, colour: [u8; 3]) {
    if x < 0 || y < 0 || x >= i64::from(image.width) || y >= i64::from(image.height) {
        return;
    }
    let i = (y as usize * image.width as usize + x as usize) * 3;
    image.data[i..i + 3].copy_from_slice(&colour);
}

fn draw_rect(image: &mut RgbImage, lo: DVec2, hi: DVec2, colour: [u8; 3], thickness: i64) {
    let (x0, y0, x1, y1) = (lo.x as i64, lo.y as i64, hi.x as i64, hi.y as i64);
    for t in 0..thickness {
        for x in x0..=x1 {
            put(image, x, y0 + t, colour);
            put(image, x, y1 - t, colour);
        }
        for y in y0..=y1 {
            put(image, x0 + t, y, colour);
            put(image, x1 - t, y, colour);
        }
    }
}

/// Digits 0-9 as 3 × 5 bitmaps (rows top down, 3 bits each).
const DIGITS: [[u8; 5]; 10] = [
    [7, 5, 5, 5, 7],
    [2, 6, 2, 2, 7],
    [7, 1, 7, 4, 7],
    [7, 1, 7, 1, 7],
    [5, 5, 7, 1, 1],
    [7, 4, 7, 1, 7],
    [7, 4, 7, 5, 7],
    [7, 1, 1, 1, 1],
    [7, 5, 7, 5, 7],
    [7, 5, 7, 1, 7],
];

/// `number` at (x, y), each font pixel a 3 × 3 block on a black plate.
fn draw_number(image: &mut RgbImage, x: i64, y: i64, number: usize, colour: [u8; 3]) {
    let digits: Vec<usize> = number
        .to_string()
        .bytes()
        .map(|b| usize::from(b - b'0'))
        .collect();
    let scale = 3;
    let width = digits.len() as i64 * 4 * scale + scale;
    for dy in 0..7 * scale {
        for dx in 0..width {
            put(image, x + dx, y + dy, [0, 0, 0]);
        }
    }
    for (k, d) in digits.iter().enumerate() {
        for (row, bits) in DIGITS[*d].iter().enumerate() {
            for col in 0..3 {
                if bits & (4 >> col) != 0 {
                    for sy in 0..scale {
                        for sx in 0..scale {
                            put(
                                image,
                                x + scale + (k as i64 * 4 + col) * scale + sx,
                                y + scale + row as i64 * scale + sy,
                                colour,
                            );
                        }
                    }
                }
            }
        }
    }
}

/// PNG bytes of an image.
pub fn png(image: &RgbImage) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    image::ImageEncoder::write_image(
        image::codecs::png::PngEncoder::new(&mut out),
        &image.data,
        image.width,
        image.height,
        image::ExtendedColorType::Rgb8,
    )
    .map_err(|e| e.to_string())?;
    Ok(out)
}

/// A file stem for an expression's evidence: its words, lower case, joined by `_`.
pub fn stem(expression: &str) -> String {
    let words: Vec<String> = expression
        .split(|c: char| !c.is_alphanumeric())
        .filter(|w| !w.is_empty())
        .take(12)
        .map(str::to_lowercase)
        .collect();
    if words.is_empty() {
        "query".into()
    } else {
        words.join("_")
    }
}

/// Write `evidence` to `dir` as `evidence.json` and one PNG per image, named `<stem>_<name>.png`.
pub fn write(dir: &Path, stem: &str, evidence: &Evidence) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    std::fs::write(
        dir.join(format!("{stem}.json")),
        serde_json::to_string_pretty(&evidence.json).unwrap_or_default(),
    )?;
    for (name, image) in &evidence.images {
        let bytes = png(image).map_err(std::io::Error::other)?;
        std::fs::write(dir.join(format!("{stem}_{name}.png")), bytes)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crops_are_clamped_to_the_image_and_empty_ones_are_none() {
        let image = RgbImage {
            width: 4,
            height: 3,
            data: (0..36).collect(),
        };
        let c = crop(&image, DVec2::new(1.0, 1.0), DVec2::new(3.0, 2.0)).unwrap();
        assert_eq!((c.width, c.height), (2, 1));
        assert_eq!(c.data, [15, 16, 17, 18, 19, 20]);
        let all = crop(&image, DVec2::splat(-5.0), DVec2::splat(50.0)).unwrap();
        assert_eq!(all, image);
        assert!(crop(&image, DVec2::new(2.0, 2.0), DVec2::new(2.0, 3.0)).is_none());
        assert!(crop(&image, DVec2::splat(f64::NAN), DVec2::splat(f64::NAN)).is_none());
    }

    #[test]
    fn stems_are_the_expression_s_words() {
        assert_eq!(
            stem("The chair, closest to the lamp!"),
            "the_chair_closest_to_the_lamp"
        );
        assert_eq!(stem("?!"), "query");
    }
}
