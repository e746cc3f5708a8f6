//! `groupforward eval map`: sim scenes no training saw, replayed through the node's stages with
//! the shipped (or given) models, the final map scored against ground truth. Writes
//! `DIR/objects.csv` (one row per object), `DIR/instances.csv` (one row per listed instance:
//! where the false positives are), `DIR/identity.csv` (where map ids changed or stood for two
//! objects), `DIR/summary.json` and `DIR/summary.md`, and prints
//! the table with each headline figure's 95% interval over scenes; `--against` an earlier run's
//! directory also gives the paired difference, so a change is judged against the spread.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::eval_command::ModelArgs;
use anyhow::{bail, Context, Result};
use groupforward::config::Config;
use groupforward::ingest::DepthValidity;
use groupforward::model::ModelsSection;
use groupforward::recon::depth_noise;
use groupforward::timing::{describe, summarise, Stage, StageSummary, StageTimes};
use groupforward::window::WindowModels;
use groupforward_harness::eval::interval::{intervals, paired_differences, Interval};
use groupforward_harness::eval::picture::top_down_svg;
use groupforward_harness::eval::run::{run_scene, SceneRun};
use groupforward_harness::eval::score::{
    attach_traces, score_instances, score_map, score_windows, trace_objects, Counts, InstanceRow,
    ObjectRow, Summary,
};
use groupforward_sim::effects::Preset;
use groupforward_sim::procedural::{generate, Split};
use groupforward_sim::scene::SceneFile;
use sha2::{Digest, Sha256};

use crate::sim::{load_scene, progress_bar};

/// Objects seen by fewer pixels over the whole trajectory are not scored (counted apart).
pub(crate) const MIN_OBJECT_PIXELS: u64 = 1000;
/// An object counts as seen by a window with this many pixels in its views.
const MIN_WINDOW_PIXELS: u64 = 200;

/// The scenes to replay: `specs` (files or `<split>:<index>`) if any, else scenes
/// `first_index..first_index + count` of `split`; with `effects` as every scene's preset.
pub fn scene_files(
    split: &str,
    first_index: u64,
    count: u64,
    specs: &[String],
    effects: Option<&str>,
) -> Result<Vec<SceneFile>> {
    let mut files = if specs.is_empty() {
        split_scenes(split, first_index, count)?
    } else {
        specs.iter().map(|s| load_scene(s)).collect::<Result<_>>()?
    };
    if let Some(name) = effects {
        let preset = Preset::parse(name).map_err(anyhow::Error::msg)?;
        for file in &mut files {
            file.apply_preset(preset);
        }
    }
    Ok(files)
}

/// Scenes `first_index..first_index + count` of a procedural split.
pub fn split_scenes(split: &str, first_index: u64, count: u64) -> Result<Vec<SceneFile>> {
    let Some(split_kind) = Split::parse(split) else {
        bail!("unknown split `{split}` (train, val, benchmark)");
    };
    (first_index..first_index + count)
        .map(|i| generate(split_kind, i).with_context(|| format!("no scene {i} in split {split}")))
        .collect()
}

/// The node's default config with the shipped models, or the config file `models` names; with
/// the models it names instead. A config file with a mistake is an error naming it.
pub fn eval_config(models: &ModelArgs) -> Result<Config> {
    let mut config = match &models.config {
        Some(path) => Config::load(path)?,
        None => Config {
            models: ModelsSection::shipped_in(&shipped_models()),
            ..Config::default()
        },
    };
    if let Some(model) = &models.model {
        config.models.reconstruction = Some(model.clone());
    }
    if let Some(semantic) = &models.semantic_model {
        config.models.semantic = Some(semantic.clone());
    }
    Ok(config)
}

pub fn shipped_models() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models")
}

/// SHA-256 of a model's ONNX file, through its manifest.
pub fn model_hash(manifest: &Path) -> Result<String> {
    let loaded = groupforward::model::manifest::Manifest::load(manifest)?;
    let bytes = std::fs::read(loaded.model_path())
        .with_context(|| format!("reading {}", loaded.model_path().display()))?;
    Ok(hex_digest(&Sha256::digest(&bytes)))
}

fn hex_digest(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// What scoring a set of scenes gave.
#[derive(Default)]
pub struct Scored {
    pub total: Counts,
    pub rows: Vec<ObjectRow>,
    pub instance_rows: Vec<InstanceRow>,
    /// Per scene, the final map's content hash (a run is deterministic: the same hash again).
    pub map_hashes: Vec<(String, String)>,
    /// Per scene: its name, counts and windows.
    pub per_scene: Vec<(String, Counts, usize)>,
    /// Per scene: its name and its map from above (SVG).
    pub pictures: Vec<(String, String)>,
    /// Rows of `identity.csv`, every scene's ([`crate::eval_identity`]).
    pub identity: Vec<String>,
    pub window_times: Vec<StageTimes>,
    pub depth: DepthValidity,
    pub model_pixels_without_depth: u64,
    pub lifted_at_neighbour_depth: u64,
    /// Per window, the depth noise at 1 m measured on its views.
    pub depth_noise_at_1m: Vec<Option<f32>>,
}

/// Replay each scene through the node's stages with `window_models` and score its map, with a
/// progress bar.
pub fn score_scenes(
    files: &[SceneFile],
    config: &Config,
    window_models: &mut WindowModels,
    what: &str,
) -> Result<Scored> {
    let bar = progress_bar(files.len() as u64, what);
    let mut scored = Scored::default();
    for file in files {
        bar.set_message(file.name.clone());
        let run: SceneRun = run_scene(file, config, window_models)
            .with_context(|| format!("scene {}", file.name))?;
        scored.add(&run);
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(scored)
}

impl Scored {
    /// Score one scene's run and add it.
    pub fn add(&mut self, run: &SceneRun) {
        let (mut scene_rows, mut counts) = score_map(
            &run.scene,
            &run.objects,
            &run.instances,
            run.room_area,
            MIN_OBJECT_PIXELS,
        );
        let traces = trace_objects(&run.objects, &run.windows, MIN_WINDOW_PIXELS);
        attach_traces(&mut scene_rows, &run.objects, &traces);
        counts.count_losses(&scene_rows);
        counts.add(&score_windows(
            &run.objects,
            &run.windows,
            MIN_WINDOW_PIXELS,
        ));
        self.total.add(&counts);
        let instance_rows = score_instances(&run.scene, &run.objects, &run.instances);
        self.pictures.push((
            run.scene.clone(),
            top_down_svg(
                &run.scene,
                &run.objects,
                &scene_rows,
                &run.instances,
                &instance_rows,
            ),
        ));
        self.identity.extend(crate::eval_identity::identity_rows(
            &run.scene,
            &run.objects,
            &run.windows,
            MIN_WINDOW_PIXELS,
        ));
        self.rows.extend(scene_rows);
        self.instance_rows.extend(instance_rows);
        self.map_hashes.push((
            run.scene.clone(),
            groupforward::graph::persist::content_hash(&run.map),
        ));
        self.window_times.extend(run.window_times.iter().cloned());
        self.depth.add(&run.depth);
        self.model_pixels_without_depth += run.model_pixels_without_depth;
        self.lifted_at_neighbour_depth += run.lifted_at_neighbour_depth;
        self.depth_noise_at_1m
            .extend(run.depth_noise_at_1m.iter().copied());
        self.per_scene
            .push((run.scene.clone(), counts, run.windows.len()));
    }
}

/// Share of the depth pixels ingest received that were invalid.
pub fn invalid_fraction(depth: &DepthValidity) -> f64 {
    depth.invalid() as f64 / depth.pixels.max(1) as f64
}

pub fn eval_map(
    files: &[SceneFile],
    models: &ModelArgs,
    effects: Option<&str>,
    against: Option<&Path>,
    out: &Path,
) -> Result<()> {
    // Read and paired with this run's scenes first: a wrong directory fails before ten minutes of
    // replay, not after.
    let before = against
        .map(|dir| -> Result<Vec<Counts>> {
            let earlier = read_scene_counts(dir)?;
            files
                .iter()
                .map(|f| {
                    earlier
                        .iter()
                        .find(|(name, _)| *name == f.name)
                        .map(|(_, counts)| *counts)
                        .with_context(|| format!(
                            "the run compared against has no scene `{}`: --against needs a run over the same scenes",
                            f.name
                        ))
                })
                .collect()
        })
        .transpose()?;
    let config = eval_config(models)?;
    let mut window_models = WindowModels::load(&config.models, &config.semantics)
        .context("loading the models (`make setup` installs ONNX Runtime)")?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let Scored {
        total,
        rows,
        instance_rows,
        map_hashes,
        per_scene,
        window_times,
        depth,
        model_pixels_without_depth,
        lifted_at_neighbour_depth,
        depth_noise_at_1m,
        pictures,
        identity,
    } = score_scenes(files, &config, &mut window_models, "eval map")?;
    write_pictures(&pictures, &out.join("maps"))?;
    crate::eval_identity::write_identity_csv(&out.join("identity.csv"), &identity)?;
    let noise_at_1m = depth_noise::median_measured(depth_noise_at_1m.iter().copied());
    let noise_windows = depth_noise_at_1m.iter().flatten().count();
    let summary = total.summary();
    let scene_counts: Vec<Counts> = per_scene.iter().map(|(_, c, _)| *c).collect();
    let spread = intervals(&scene_counts);
    // Scenes are scored in the order of `files`, the order `before` was paired in.
    let difference = before.map(|before| {
        let recorded: Vec<Counts> = scene_counts.iter().map(as_recorded).collect();
        paired_differences(&recorded, &before)
    });
    let mut csv = csv_writer(&out.join("objects.csv"))?;
    writeln!(
        csv,
        "scene,object,class,pixels,outcome,instance,iou,name,name_correct,centre_error_m,size_ratio,\
         window_sightings,window_found,window_best_iou,pixel_best_iou,in_best,split,to_structure,\
         unassigned,not_lifted,noise,edge,speck,support,other_object,impurity,map_best_iou,lost_at"
    )?;
    for r in &rows {
        let lost_at = match r.lost_at {
            Some(stage) => serde_json::to_value(stage)?
                .as_str()
                .unwrap_or("?")
                .to_owned(),
            None => String::new(),
        };
        writeln!(
            csv,
            "{},{},{},{},{},{},{:.4},{},{},{:.4},{:.4},{},{},{:.4},{:.4},{:.3},{:.3},{:.3},{:.3},{},{:.3},{:.4},{}",
            r.scene,
            r.object,
            r.class,
            r.pixels,
            serde_json::to_value(r.outcome)?.as_str().unwrap_or("?"),
            r.instance,
            r.iou,
            r.name,
            r.name_correct,
            r.centre_error_m,
            r.size_ratio,
            r.trace.window_sightings,
            r.trace.window_found,
            r.trace.window_best_iou,
            r.trace.pixel_best_iou,
            r.trace.in_best,
            r.trace.split,
            r.trace.to_structure,
            r.trace.unassigned,
            r.trace
                .unassigned_by
                .iter()
                .map(|share| format!("{share:.3}"))
                .collect::<Vec<_>>()
                .join(","),
            r.trace.impurity,
            r.trace.map_best_iou,
            lost_at
        )?;
    }
    let mut csv = csv_writer(&out.join("instances.csv"))?;
    writeln!(
        csv,
        "scene,instance,name,name_score,observations,gaussians,centre_x,centre_y,centre_z,size_x,size_y,size_z,outcome,object,object_class,iou"
    )?;
    for r in &instance_rows {
        writeln!(
            csv,
            "{},{},{},{:.3},{},{},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{},{},{},{:.4}",
            r.scene,
            r.instance,
            r.name,
            r.name_score,
            r.observations,
            r.gaussians,
            r.centre[0],
            r.centre[1],
            r.centre[2],
            r.size[0],
            r.size[1],
            r.size[2],
            serde_json::to_value(r.outcome)?.as_str().unwrap_or("?"),
            r.object,
            r.object_class,
            r.iou
        )?;
    }
    let stages = summarise(&window_times);
    let window = stages.iter().find(|s| s.stage == Stage::Window).copied();
    let reconstruction = config.models.reconstruction.clone().unwrap_or_default();
    let semantic = config.models.semantic.clone().unwrap_or_default();
    let json = serde_json::json!({
        "summary": summary,
        "counts": total,
        "map_hashes": map_hashes
            .iter()
            .map(|(scene, hash)| (scene.clone(), serde_json::json!(hash)))
            .collect::<serde_json::Map<_, _>>(),
        "intervals_95": intervals_json(&spread),
        "against": match (&against, &difference) {
            (Some(dir), Some(d)) => serde_json::json!({
                "run": dir.display().to_string(), "difference_95": intervals_json(d)}),
            _ => serde_json::Value::Null,
        },
        "scenes": per_scene.iter().map(|(name, counts, windows)| serde_json::json!({
            "scene": name, "windows": windows, "summary": counts.summary(),
            "counts": counts})).collect::<Vec<_>>(),
        "depth": {
            "pixels": depth.pixels,
            "invalid": depth.invalid(),
            "invalid_fraction": invalid_fraction(&depth),
            "missing": depth.missing,
            "out_of_range": depth.out_of_range,
            "isolated": depth.isolated,
            "model_pixels_without_sensor_depth": model_pixels_without_depth,
            "lifted_at_neighbour_depth": lifted_at_neighbour_depth,
            "noise_at_1m_m": noise_at_1m,
            "noise_measured_windows": noise_windows,
        },
        "window_millis": {
            "p50": window.map_or(0.0, |w| w.p50_ms),
            "p99": window.map_or(0.0, |w| w.p99_ms),
            "windows": window_times.len(),
            "stages": stages_json(&stages),
        },
        "models": {
            "reconstruction": reconstruction.display().to_string(),
            "reconstruction_sha256": model_hash(&reconstruction)?,
            "semantic": semantic.display().to_string(),
            "semantic_sha256": model_hash(&semantic)?,
        },
        "config": {
            "file": models.config.as_ref().map(|p| p.display().to_string()),
            "window": config.window,
            "min_object_pixels": MIN_OBJECT_PIXELS,
            "min_window_pixels": MIN_WINDOW_PIXELS,
            "effects": effects.unwrap_or("as the scene files say"),
        },
    });
    std::fs::write(
        out.join("summary.json"),
        serde_json::to_string_pretty(&json)?,
    )?;
    let mut table = markdown(&summary, &per_scene);
    table.push_str(&format!(
        "\n95% intervals over the {} scenes (bootstrap): {}\n",
        per_scene.len(),
        describe_intervals(&spread, false)
    ));
    if let (Some(dir), Some(d)) = (against, &difference) {
        table.push_str(&format!(
            "against {} (same scenes, paired): {}\n",
            dir.display(),
            describe_intervals(d, true)
        ));
    }
    std::fs::write(out.join("summary.md"), &table)?;
    print!("{table}");
    println!(
        "depth: {:.1}% of {} pixels invalid ({} missing, {} out of range, {} isolated); of {} model pixels without depth, {} lifted at a measured neighbour's depth (the model's depth agrees with it), the rest not lifted",
        100.0 * invalid_fraction(&depth),
        depth.pixels,
        depth.missing,
        depth.out_of_range,
        depth.isolated,
        model_pixels_without_depth,
        lifted_at_neighbour_depth
    );
    println!(
        "depth noise at 1 m: {} ({noise_windows} of {} windows measured it; it grows with range²)",
        noise_at_1m.map_or("none measured".to_owned(), |n| format!("{:.1} mm", n * 1e3)),
        depth_noise_at_1m.len()
    );
    println!(
        "window pass to map update: {}; wrote {}",
        describe(&stages),
        out.display()
    );
    Ok(())
}

/// Per-stage p50 / p99 as JSON, keyed by stage name.
pub fn stages_json(stages: &[StageSummary]) -> serde_json::Value {
    stages
        .iter()
        .map(|s| {
            (
                s.stage.name().to_owned(),
                serde_json::json!({"p50_ms": s.p50_ms, "p99_ms": s.p99_ms, "count": s.count}),
            )
        })
        .collect::<serde_json::Map<_, _>>()
        .into()
}

/// Each scene's map from above, as `dir/<scene>.svg`.
fn write_pictures(pictures: &[(String, String)], dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    for (scene, svg) in pictures {
        let path = dir.join(format!("{scene}.svg"));
        std::fs::write(&path, svg).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

fn csv_writer(path: &Path) -> Result<std::io::BufWriter<std::fs::File>> {
    Ok(std::io::BufWriter::new(
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?,
    ))
}

/// `counts` as [`read_scene_counts`] would read them back from `summary.json`: serde_json's float
/// parsing is not always correctly rounded (an ulp off for some sums), so a run paired with an
/// earlier one compares like with like and two identical runs differ by exactly zero.
fn as_recorded(counts: &Counts) -> Counts {
    serde_json::to_string(counts)
        .ok()
        .and_then(|text| serde_json::from_str(&text).ok())
        .unwrap_or(*counts)
}

/// Per scene, its counts, from an earlier run's `summary.json`.
fn read_scene_counts(dir: &Path) -> Result<Vec<(String, Counts)>> {
    #[derive(serde::Deserialize)]
    struct Run {
        scenes: Vec<SceneEntry>,
    }
    #[derive(serde::Deserialize)]
    struct SceneEntry {
        scene: String,
        counts: Counts,
    }
    let path = dir.join("summary.json");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let run: Run = serde_json::from_str(&text).with_context(|| {
        format!(
            "{} holds no per-scene counts (written by `eval map` since the intervals were added)",
            path.display()
        )
    })?;
    Ok(run
        .scenes
        .into_iter()
        .map(|s| (s.scene, s.counts))
        .collect())
}

fn intervals_json(intervals: &[Interval]) -> serde_json::Value {
    intervals
        .iter()
        .map(|i| {
            (
                i.name.to_owned(),
                serde_json::json!({"value": i.value, "low": i.low, "high": i.high}),
            )
        })
        .collect::<serde_json::Map<_, _>>()
        .into()
}

/// `recall_at_25 75.2% (71.0 to 79.1)`; a difference in points (mean IoU stays a ratio) with
/// whether its interval excludes zero.
fn describe_intervals(intervals: &[Interval], difference: bool) -> String {
    intervals
        .iter()
        .map(|i| {
            let (scale, digits, unit) = match (i.name == "mean_iou", difference) {
                (true, _) => (1.0, 3, ""),
                (false, false) => (100.0, 1, "%"),
                (false, true) => (100.0, 1, " pts"),
            };
            let (value, low, high) = (scale * i.value, scale * i.low, scale * i.high);
            if difference {
                let verdict = if i.excludes_zero() {
                    "beyond the spread"
                } else {
                    "within the spread"
                };
                format!(
                    "{} {value:+.digits$}{unit} ({low:+.digits$} to {high:+.digits$}, {verdict})",
                    i.name
                )
            } else {
                format!(
                    "{} {value:.digits$}{unit} ({low:.digits$} to {high:.digits$})",
                    i.name
                )
            }
        })
        .collect::<Vec<_>>()
        .join("; ")
}

fn markdown(total: &Summary, per_scene: &[(String, Counts, usize)]) -> String {
    let mut out = String::from(
        "| scene | objects | listed | recall@0.25 | recall@0.5 | mean IoU | precision | duplicates | merged | names | room | id switches / 100 | map id changes / 100 | ids on two objects | window recall@0.25 | window precision |\n\
         | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n",
    );
    let row = |name: &str, s: &Summary| {
        format!(
            "| {name} | {} | {} | {:.1}% | {:.1}% | {:.3} | {:.1}% | {:.1}% | {} | {:.1}% | {} | {:.2} | {:.2} | {} | {:.1}% | {:.1}% |\n",
            s.objects_scored,
            s.instances_listed,
            100.0 * s.recall_at_25,
            100.0 * s.recall_at_50,
            s.mean_iou,
            100.0 * s.precision,
            100.0 * s.duplicate_rate,
            s.merged_objects,
            100.0 * s.name_top1,
            s.room_instances,
            s.id_switches_per_100_sightings,
            s.map_id_changes_per_100_sightings,
            s.map_ids_shared,
            100.0 * s.window_recall_at_25,
            100.0 * s.window_precision,
        )
    };
    for (name, counts, _) in per_scene {
        out.push_str(&row(name, &counts.summary()));
    }
    out.push_str(&row("**all**", total));
    out.push_str(&format!(
        "\nObjects not found at IoU 0.25: {} lost in the windows (no window grouped them as themselves), \
         {} in fusion (a window did, the map never held them), {} later (the map held them, \
         then lost them); per object in objects.csv (`lost_at`).\n",
        total.lost_in_windows, total.lost_in_fusion, total.lost_later
    ));
    out
}
