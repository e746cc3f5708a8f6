//! `groupforward sim ...`: render a scene, record a bag, write a training dataset or a referring
//! benchmark set.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::Subcommand;
use groupforward_sim::effects::Preset;
use groupforward_sim::procedural::{self, Split};
use groupforward_sim::record::{ColorFormat, DepthFormat, RecordOptions};
use groupforward_sim::scene::SceneFile;
use groupforward_sim::simulation::Simulation;

#[derive(Debug, Subcommand)]
pub enum SimCommand {
    /// Render one frame: RGB as the sensor records it, depth (16-bit mm), instance and class ids
    /// (16-bit) as PNGs, plus a side-by-side preview.
    Render {
        /// A scene file (TOML) or a procedural scene `<split>:<index>` (e.g. `val:3`).
        scene: String,
        /// Frame of the trajectory.
        #[arg(long, default_value_t = 0)]
        frame: usize,
        /// Output directory.
        #[arg(long, default_value = "sim_render")]
        out: PathBuf,
    },
    /// Record the scene's whole trajectory as a rosbag2 bag directory (MCAP + metadata.yaml).
    Record {
        /// A scene file (TOML) or a procedural scene `<split>:<index>`.
        scene: String,
        /// Bag directory to create.
        #[arg(long)]
        out: PathBuf,
        /// Colour as CompressedImage (`png` or `jpeg`) instead of a raw rgb8 Image.
        #[arg(long)]
        compressed: Option<String>,
        /// Depth as 16UC1 millimetres instead of 32FC1 metres.
        #[arg(long)]
        depth_mm: bool,
        /// Leave out the `/gt/...` ground-truth topics.
        #[arg(long)]
        no_ground_truth: bool,
        /// Replace the scene's effects by a preset: `clean`, `realistic`, `dropout:<p>`, or
        /// `realistic:<effect>,...` (only those of realistic's effects).
        #[arg(long)]
        effects: Option<String>,
    },
    /// Write a training dataset of procedural scenes.
    Dataset {
        #[arg(long, default_value = "train")]
        split: String,
        #[arg(long, default_value_t = 100)]
        samples: usize,
        /// Scene index of the first sample within the split.
        #[arg(long, default_value_t = 0)]
        first_index: u64,
        #[arg(long, default_value_t = 4)]
        views: usize,
        #[arg(long, default_value_t = 128)]
        width: u32,
        #[arg(long, default_value_t = 96)]
        height: u32,
        /// Draw each sample's effects from a preset (`realistic`: a quarter clean, the others a
        /// consumer depth camera with 1-30% dropout).
        #[arg(long)]
        effects: Option<String>,
        /// Render at this sensor resolution (e.g. `320x240`, the benchmark camera's) and resample
        /// to `--width × --height` as the node resamples camera images, so sensor effects act at
        /// the scale the node meets them.
        #[arg(long, value_parser = parse_resolution)]
        sensor: Option<(u32, u32)>,
        #[arg(long)]
        out: PathBuf,
    },
    /// Write a referring benchmark set: scene files and expressions generated from ground truth.
    Benchmark {
        #[arg(long, default_value = "benchmark")]
        split: String,
        #[arg(long, default_value_t = 20)]
        scenes: u64,
        #[arg(long, default_value_t = 0)]
        first_index: u64,
        #[arg(long)]
        out: PathBuf,
    },
    /// Write the default vocabulary file that the node embeds: the simulator's object classes with
    /// their priors measured on the training rooms (`--out node/data/default_vocabulary.yaml`
    /// after the class library or the training split changed); without `--out`, print it.
    Vocabulary {
        #[arg(long)]
        out: Option<PathBuf>,
    },
}

/// A scene file path, or `<split>:<index>` for a procedural scene.
pub fn load_scene(spec: &str) -> Result<SceneFile> {
    if let Some((split, index)) = spec.split_once(':') {
        if let (Some(split), Ok(index)) = (Split::parse(split), index.parse::<u64>()) {
            return procedural::generate(split, index)
                .with_context(|| format!("no scene {index} in split {split}"));
        }
    }
    Ok(SceneFile::load(Path::new(spec))?)
}

fn parse_split(name: &str) -> Result<Split> {
    Split::parse(name).with_context(|| format!("unknown split `{name}` (train, val, benchmark)"))
}

pub fn progress_bar(len: u64, what: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len);
    if let Ok(style) = indicatif::ProgressStyle::with_template(&format!(
        "{what} {{bar:40}} {{pos}}/{{len}} [{{elapsed_precise}} < {{eta}}]"
    )) {
        bar.set_style(style);
    }
    bar
}

pub fn run(command: SimCommand) -> Result<()> {
    match command {
        SimCommand::Render { scene, frame, out } => render(&load_scene(&scene)?, frame, &out),
        SimCommand::Vocabulary { out } => {
            let text = groupforward_harness::vocabulary::default_vocabulary_yaml();
            match out {
                Some(path) => std::fs::write(&path, text)
                    .with_context(|| format!("cannot write {}", path.display())),
                None => {
                    print!("{text}");
                    Ok(())
                }
            }
        }
        SimCommand::Record {
            scene,
            out,
            compressed,
            depth_mm,
            no_ground_truth,
            effects,
        } => {
            let color = match compressed.as_deref() {
                None => ColorFormat::Raw,
                Some("png") => ColorFormat::Png,
                Some("jpeg") | Some("jpg") => ColorFormat::Jpeg { quality: 90 },
                Some(other) => bail!("--compressed {other}: expected png or jpeg"),
            };
            let options = RecordOptions {
                color,
                depth: if depth_mm {
                    DepthFormat::Millimetres16
                } else {
                    DepthFormat::Metres32
                },
                ground_truth: !no_ground_truth,
                ..RecordOptions::default()
            };
            let mut file = load_scene(&scene)?;
            if let Some(name) = &effects {
                file.apply_preset(Preset::parse(name).map_err(anyhow::Error::msg)?);
            }
            let sim = Simulation::new(file)?;
            let bar = progress_bar(sim.frame_count() as u64, "recording");
            let started = Instant::now();
            let summary = groupforward_sim::record::record_to_dir(&sim, &options, &out, &|n| {
                bar.set_position(n as u64)
            })?;
            bar.finish_and_clear();
            println!(
                "recorded {} frames ({} dropped), {} messages into {} in {:.2} s",
                summary.frames,
                summary.dropped,
                summary.messages,
                out.display(),
                started.elapsed().as_secs_f64()
            );
            Ok(())
        }
        SimCommand::Dataset {
            split,
            samples,
            first_index,
            views,
            width,
            height,
            effects,
            sensor,
            out,
        } => {
            let effects = effects
                .as_deref()
                .map(Preset::parse)
                .transpose()
                .map_err(anyhow::Error::msg)?;
            let options = groupforward_sim::dataset::DatasetOptions {
                effects,
                split: parse_split(&split)?,
                first_index,
                samples,
                views,
                width,
                height,
                sensor,
                ..Default::default()
            };
            let bar = progress_bar(samples as u64, "dataset");
            let started = Instant::now();
            let summary = groupforward_sim::dataset::write_dataset(&out, &options, &|n| {
                bar.set_position(n as u64)
            })?;
            bar.finish_and_clear();
            println!(
                "wrote {} samples ({} views of {width}x{height}) to {}: {:.1} MB in {:.1} s; {:.0}% of pixels show objects",
                summary.samples,
                summary.views,
                out.display(),
                summary.bytes as f64 / 1e6,
                started.elapsed().as_secs_f64(),
                summary.object_pixel_fraction * 100.0
            );
            Ok(())
        }
        SimCommand::Benchmark {
            split,
            scenes,
            first_index,
            out,
        } => benchmark(parse_split(&split)?, first_index, scenes, &out),
    }
}

fn benchmark(split: Split, first_index: u64, scenes: u64, out: &Path) -> Result<()> {
    let scene_dir = out.join("scenes");
    std::fs::create_dir_all(&scene_dir)?;
    let path = out.join("expressions.jsonl");
    let mut lines = std::io::BufWriter::new(std::fs::File::create(&path)?);
    let mut counts = std::collections::BTreeMap::new();
    let mut total = 0usize;
    for index in first_index..first_index + scenes {
        let file = procedural::generate(split, index)
            .with_context(|| format!("no scene {index} in split {split}"))?;
        std::fs::write(
            scene_dir.join(format!("{}.toml", file.name)),
            file.to_toml()?,
        )?;
        for expression in groupforward_sim::referring::scene_expressions(&file)? {
            let mut value = serde_json::to_value(&expression)?;
            value["scene"] = serde_json::Value::String(file.name.clone());
            writeln!(lines, "{}", serde_json::to_string(&value)?)?;
            *counts.entry(expression.relation).or_insert(0usize) += 1;
            total += 1;
        }
    }
    lines.flush()?;
    println!(
        "{total} referring expressions over {scenes} {split} scenes -> {}",
        path.display()
    );
    for (relation, count) in counts {
        println!("  {:<12} {count:>5}", format!("{relation:?}"));
    }
    Ok(())
}

fn render(file: &SceneFile, frame: usize, out: &Path) -> Result<()> {
    let sim = Simulation::new(file.clone())?;
    if frame >= sim.frame_count() {
        bail!("the trajectory has {} frames", sim.frame_count());
    }
    let rendered = sim.frame(frame);
    if rendered.dropped {
        bail!("frame {frame} is dropped by the scene's frame_drops effect");
    }
    std::fs::create_dir_all(out)?;
    for (view, camera) in rendered.views.iter().zip(&file.cameras) {
        let (w, h) = (view.truth.width, view.truth.height);
        let rgb =
            image::RgbImage::from_raw(w, h, view.sensor_rgb().to_vec()).context("rgb size")?;
        let millimetres: Vec<u16> = view
            .sensor_depth()
            .iter()
            .map(|d| {
                if d.is_finite() {
                    (d * 1000.0).round().clamp(0.0, 65535.0) as u16
                } else {
                    0
                }
            })
            .collect();
        let depth = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, millimetres)
            .context("depth size")?;
        let instance =
            image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, view.truth.instance.clone())
                .context("instance size")?;
        let class =
            image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w, h, view.truth.class.clone())
                .context("class size")?;
        let stem = format!("{}_{frame:04}_{}", file.name, camera.name);
        rgb.save(out.join(format!("{stem}_rgb.png")))?;
        depth.save(out.join(format!("{stem}_depth_mm.png")))?;
        instance.save(out.join(format!("{stem}_instance.png")))?;
        class.save(out.join(format!("{stem}_class.png")))?;
        preview(&rgb, view.sensor_depth(), &view.truth.instance)?
            .save(out.join(format!("{stem}_preview.png")))?;
        println!(
            "wrote {}/{stem}_{{rgb,depth_mm,instance,class,preview}}.png",
            out.display()
        );
    }
    Ok(())
}

/// RGB | depth (near bright, invalid black) | instances in distinct colours.
fn preview(rgb: &image::RgbImage, depth: &[f32], instance: &[u16]) -> Result<image::RgbImage> {
    let (w, h) = rgb.dimensions();
    let max_depth = depth
        .iter()
        .copied()
        .filter(|d| d.is_finite())
        .fold(0.0f32, f32::max)
        .max(1e-3);
    let mut out = image::RgbImage::new(3 * w, h);
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            out.put_pixel(x, y, *rgb.get_pixel(x, y));
            let d = if depth[i].is_finite() {
                (255.0 * (1.0 - depth[i] / max_depth)) as u8
            } else {
                0
            };
            out.put_pixel(w + x, y, image::Rgb([d, d, d]));
            let id = u32::from(instance[i]);
            let color = if id == 0 {
                [0, 0, 0]
            } else {
                [
                    (id * 97 % 200 + 55) as u8,
                    (id * 53 % 200 + 55) as u8,
                    (id * 151 % 200 + 55) as u8,
                ]
            };
            out.put_pixel(2 * w + x, y, image::Rgb(color));
        }
    }
    Ok(out)
}

/// `WIDTHxHEIGHT`, both positive.
fn parse_resolution(text: &str) -> Result<(u32, u32), String> {
    let bad = || format!("expected WIDTHxHEIGHT (e.g. 320x240), got {text:?}");
    let (w, h) = text.split_once(['x', 'X']).ok_or_else(bad)?;
    let parse = |s: &str| s.trim().parse::<u32>().ok().filter(|v| *v > 0);
    Ok((parse(w).ok_or_else(bad)?, parse(h).ok_or_else(bad)?))
}
