//! `groupforward bench sweep`: what accuracy costs in time. Each setting (views per window, the
//! HDBSCAN subsample and minimum cluster size, the RGB-D or RGB model) replays the same recorded
//! scenes through the node's stages, timed per stage, and scores the map with `eval map`'s
//! yardstick. Writes `sweep.csv`, `sweep.md` and `pareto.svg` (recall against window latency).

use std::path::Path;

use anyhow::{Context, Result};
use groupforward::timing::{summarise, Stage, StageSummary};
use groupforward::window::WindowModels;
use groupforward_harness::eval::run::{record_scene, replay_scene, RecordedScene};
use groupforward_sim::scene::SceneFile;

use crate::eval::{eval_config, shipped_models, Scored};
use crate::eval_command::ModelArgs;
use crate::sim::progress_bar;

/// One point of the sweep: the shipped default with one knob turned.
#[derive(Debug, Clone, PartialEq)]
pub struct Setting {
    pub name: String,
    pub views: usize,
    /// HDBSCAN runs on at most this many Gaussians (an even stride), the rest are assigned.
    pub max_cluster_points: usize,
    pub min_cluster_size: usize,
    /// HDBSCAN's neighbours that define a point's core distance.
    pub min_samples: usize,
    /// Reconstruction model manifest, relative to `models/`.
    pub model: &'static str,
    /// ONNX Runtime's idle threads spin (`models.intra_op_spinning`).
    pub spinning: bool,
    /// Keyframes' semantic features computed on arrival (`window.features_ahead`).
    pub features_ahead: bool,
    /// A second HDBSCAN over the first one's noise (`group::ResidualPass`).
    pub residual: Option<groupforward::group::ResidualPass>,
    /// HDBSCAN's grid (`group::GroupingParams::resolution`; 0: every embedding on its own).
    pub resolution: f32,
}

const RGBD: &str = "groupforward-mini-rgbd.toml";
const RGB: &str = "groupforward-mini-rgb.toml";
/// The default's weights taking 192 × 144 instead of the 128 × 96 they were trained at.
const RGBD_192X144: &str = "groupforward-mini-rgbd-192x144.toml";

impl Setting {
    fn default_setting() -> Self {
        let grouping = groupforward::group::GroupingParams::default();
        Self {
            name: "default".into(),
            views: groupforward::window::WindowSection::default().views,
            max_cluster_points: grouping.max_cluster_points,
            min_cluster_size: grouping.hdbscan.min_cluster_size,
            min_samples: grouping.hdbscan.min_samples,
            model: RGBD,
            spinning: groupforward::model::ModelsSection::default().intra_op_spinning,
            features_ahead: groupforward::window::WindowSection::default().features_ahead,
            residual: grouping.residual,
            resolution: grouping.resolution,
        }
    }

    fn with(name: &str, change: impl FnOnce(&mut Self)) -> Self {
        let mut setting = Self::default_setting();
        setting.name = name.into();
        change(&mut setting);
        setting
    }
}

/// The settings of a full sweep, or of `--quick` (the default and one cheaper point).
pub fn settings(quick: bool) -> Vec<Setting> {
    let mut all = vec![
        Setting::default_setting(),
        Setting::with("views_2", |s| s.views = 2),
    ];
    if quick {
        return all;
    }
    all.extend([
        Setting::with("views_8", |s| s.views = 8),
        Setting::with("views_16", |s| s.views = 16),
        Setting::with("views_24", |s| s.views = 24),
        Setting::with("subsample_12k", |s| s.max_cluster_points = 12_000),
        Setting::with("subsample_8k", |s| s.max_cluster_points = 8_000),
        Setting::with("subsample_8k_min_15", |s| {
            s.max_cluster_points = 8_000;
            s.min_cluster_size = 15;
        }),
        // Half the default's subsample (16,384 of ~49k Gaussians) with both density parameters
        // halved too, so the clusters are judged at the same density.
        Setting::with("subsample_8k_scaled", |s| {
            s.max_cluster_points = 8_192;
            s.min_cluster_size = 15;
            s.min_samples = 5;
        }),
        // The same subsample at the density min cluster 15 allows on the default's: small objects
        // kept, map ids less stable (benchmark 100-129: node/doc/bench/sweep_grouping_100-129.md).
        Setting::with("subsample_8k_min_8", |s| {
            s.max_cluster_points = 8_192;
            s.min_cluster_size = 8;
            s.min_samples = 5;
        }),
        Setting::with("subsample_40k", |s| s.max_cluster_points = 40_000),
        Setting::with("min_cluster_15", |s| s.min_cluster_size = 15),
        Setting::with("min_cluster_60", |s| s.min_cluster_size = 60),
        // The default before the residual pass was (2026-11-29), side by side with it.
        Setting::with("first_pass_only", |s| s.residual = None),
        // The default before HDBSCAN ran on a grid of the embeddings (2026-11-29).
        Setting::with("exact_hdbscan", |s| s.resolution = 0.0),
        Setting::with("rgb_model", |s| s.model = RGB),
        Setting::with("model_192x144", |s| s.model = RGBD_192X144),
        // The shipped default before its speed work (2026-11-25), side by side with it.
        Setting::with("ort_spinning", |s| s.spinning = true),
        Setting::with("features_in_window", |s| s.features_ahead = false),
        Setting::with("previous_default", |s| {
            s.spinning = true;
            s.features_ahead = false;
        }),
    ]);
    all
}

/// [`settings`], or those of them `only` names (all when it is empty); a name the sweep does
/// not know is an error that lists the known ones.
pub fn chosen_settings(quick: bool, only: &[String]) -> Result<Vec<Setting>> {
    let all = settings(quick);
    if only.is_empty() {
        return Ok(all);
    }
    let known: Vec<&str> = all.iter().map(|s| s.name.as_str()).collect();
    if let Some(unknown) = only.iter().find(|n| !known.contains(&n.as_str())) {
        anyhow::bail!(
            "no sweep setting {unknown:?}; the settings are {}",
            known.join(", ")
        );
    }
    Ok(all.into_iter().filter(|s| only.contains(&s.name)).collect())
}

/// One setting's result.
struct Point {
    setting: Setting,
    scored: Scored,
    stages: Vec<StageSummary>,
}

impl Point {
    fn stage(&self, stage: Stage) -> Option<StageSummary> {
        self.stages.iter().find(|s| s.stage == stage).copied()
    }

    fn window_p50(&self) -> f64 {
        self.stage(Stage::Window).map_or(f64::NAN, |s| s.p50_ms)
    }
}

/// Run every setting on `files`, `rounds` times in turn (a round replays every setting once:
/// timings of all rounds are pooled, so drift of the machine falls on every setting alike; the
/// maps are the same each round and are scored from the first).
/// `reproduce`: the command line that reruns it, for the report.
pub fn sweep(
    files: &[SceneFile],
    settings: &[Setting],
    rounds: usize,
    reproduce: &str,
    out: &Path,
) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    // Every setting replays the same recordings (rendering once, not once per setting).
    let bar = progress_bar(files.len() as u64, "recording scenes");
    let mut recorded: Vec<RecordedScene> = Vec::new();
    for file in files {
        bar.set_message(file.name.clone());
        recorded.push(record_scene(file).with_context(|| format!("scene {}", file.name))?);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let mut points: Vec<Point> = Vec::new();
    let mut loaded: Option<((&'static str, bool), WindowModels)> = None;
    let runs =
        (0..rounds.max(1)).flat_map(|round| settings.iter().enumerate().map(move |s| (round, s)));
    for (round, (index, setting)) in runs {
        let mut config = eval_config(&ModelArgs::reconstruction(Some(
            shipped_models().join(setting.model),
        )))?;
        config.window.views = setting.views;
        config.window.features_ahead = setting.features_ahead;
        config.models.intra_op_spinning = setting.spinning;
        let key = (setting.model, setting.spinning);
        // More views than the default's four see the same stretch of the trajectory more densely
        // (keyframes closer together), so windows span what a default window spans and short
        // scenes still fill them.
        if setting.views > 4 {
            let denser = 4.0 / setting.views as f64;
            config.window.min_translation_m *= denser;
            config.window.min_rotation_deg *= denser;
            config.window.max_interval_secs *= denser;
            config.window.max_keyframes = config.window.max_keyframes.max(setting.views);
        }
        if loaded
            .as_ref()
            .is_none_or(|(loaded_key, _)| *loaded_key != key)
        {
            let mut models = WindowModels::load(&config.models, &config.semantics)
                .context("loading the models (`make setup` installs ONNX Runtime)")?;
            // A fresh session's first passes allocate and plan: warm up untimed, so the setting
            // measured right after a load is not the slower for it.
            if let Some(first) = recorded.first() {
                replay_scene(first, &config, &mut models)
                    .with_context(|| format!("{}: warm-up on {}", setting.name, first.scene))?;
            }
            loaded = Some((key, models));
        }
        let Some((_, models)) = loaded.as_mut() else {
            unreachable!("loaded above")
        };
        models.grouping.max_cluster_points = setting.max_cluster_points;
        models.grouping.hdbscan.min_cluster_size = setting.min_cluster_size;
        models.grouping.hdbscan.min_samples = setting.min_samples;
        models.grouping.residual = setting.residual;
        models.grouping.resolution = setting.resolution;
        let bar = progress_bar(
            recorded.len() as u64,
            &format!("{} (round {})", setting.name, round + 1),
        );
        let mut scored = Scored::default();
        for scene in &recorded {
            bar.set_message(scene.scene.clone());
            let run = replay_scene(scene, &config, models)
                .with_context(|| format!("{}: scene {}", setting.name, scene.scene))?;
            scored.add(&run);
            bar.inc(1);
        }
        bar.finish_and_clear();
        if let Some(point) = points.get_mut(index) {
            point.scored.window_times.extend(scored.window_times);
            point.stages = summarise(&point.scored.window_times);
            continue;
        }
        let stages = summarise(&scored.window_times);
        let point = Point {
            setting: setting.clone(),
            scored,
            stages,
        };
        let s = point.scored.total.summary();
        eprintln!(
            "{:<20} window p50 {:>6.0} ms   recall@0.25 {:>5.1}%   precision {:>5.1}%",
            setting.name,
            point.window_p50(),
            100.0 * s.recall_at_25,
            100.0 * s.precision
        );
        points.push(point);
    }
    let threads = rayon::current_num_threads();
    let rounds = rounds.max(1);
    std::fs::write(out.join("sweep.csv"), csv(&points, rounds))?;
    let md = markdown(&points, files.len(), threads, rounds, reproduce);
    std::fs::write(out.join("sweep.md"), &md)?;
    pareto_chart(&out.join("pareto.svg"), &points)?;
    print!("{md}");
    println!("wrote {}", out.join("sweep.{csv,md}, pareto.svg").display());
    Ok(())
}

fn csv(points: &[Point], rounds: usize) -> String {
    let mut out = String::from(
        "setting,views,max_cluster_points,min_cluster_size,min_samples,model,intra_op_spinning,features_ahead,windows,window_p50_ms,window_p99_ms",
    );
    for stage in Stage::WINDOW_PASS {
        out.push_str(&format!(",{}_p50_ms", stage.name()));
    }
    out.push_str(",recall_at_25,recall_at_50,precision,duplicate_rate,merged_objects,name_top1,room_instances,id_switches_per_100_sightings,objects_scored\n");
    for p in points {
        let s = p.scored.total.summary();
        let window = p.stage(Stage::Window);
        out.push_str(&format!(
            "{},{},{},{},{},{},{},{},{},{:.2},{:.2}",
            p.setting.name,
            p.setting.views,
            p.setting.max_cluster_points,
            p.setting.min_cluster_size,
            p.setting.min_samples,
            p.setting.model.trim_end_matches(".toml"),
            p.setting.spinning,
            p.setting.features_ahead,
            window.map_or(0, |w| w.count / rounds as u64),
            window.map_or(f64::NAN, |w| w.p50_ms),
            window.map_or(f64::NAN, |w| w.p99_ms),
        ));
        for stage in Stage::WINDOW_PASS {
            out.push_str(&format!(
                ",{:.2}",
                p.stage(stage).map_or(f64::NAN, |s| s.p50_ms)
            ));
        }
        out.push_str(&format!(
            ",{:.4},{:.4},{:.4},{:.4},{},{:.4},{},{:.3},{}\n",
            s.recall_at_25,
            s.recall_at_50,
            s.precision,
            s.duplicate_rate,
            s.merged_objects,
            s.name_top1,
            s.room_instances,
            s.id_switches_per_100_sightings,
            s.objects_scored
        ));
    }
    out
}

/// Settings that ran windows and that no other setting beats on both window p50 and
/// recall@0.25.
fn pareto_front(points: &[Point]) -> Vec<usize> {
    let recall = |p: &Point| p.scored.total.summary().recall_at_25;
    let mut front: Vec<usize> = (0..points.len())
        .filter(|&i| points[i].window_p50().is_finite())
        .filter(|&i| {
            !points.iter().enumerate().any(|(j, q)| {
                j != i
                    && q.window_p50() <= points[i].window_p50()
                    && recall(q) >= recall(&points[i])
                    && (q.window_p50() < points[i].window_p50() || recall(q) > recall(&points[i]))
            })
        })
        .collect();
    front.sort_by(|&a, &b| points[a].window_p50().total_cmp(&points[b].window_p50()));
    front
}

fn markdown(
    points: &[Point],
    scenes: usize,
    threads: usize,
    rounds: usize,
    reproduce: &str,
) -> String {
    let front = pareto_front(points);
    let mut md = format!(
        "Accuracy against time: each setting replays the same {scenes} recorded benchmark scene(s) through the node's stages (every window, as `eval map` does) and scores the final map. Window = model pass to map update, {threads} threads; p50 / p99 over all windows of {rounds} round(s), the settings taking turns; windows = per round. Settings with more than 4 views take keyframes proportionally closer together (a window spans the same stretch of trajectory, seen by more views). Pareto-optimal settings (no other is both faster and more accurate on recall@0.25) are marked *.\n\n| setting | views | HDBSCAN subsample | min cluster / samples | model | windows | window p50 / p99 (ms) | model | group | semantics | fusion | recall@0.25 | recall@0.5 | precision | duplicates | names | id switches / 100 |\n| --- | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n"
    );
    for (i, p) in points.iter().enumerate() {
        let s = p.scored.total.summary();
        let ms = |stage: Stage| {
            p.stage(stage)
                .map_or("-".to_owned(), |s| format!("{:.0}", s.p50_ms))
        };
        let window = p.stage(Stage::Window);
        md.push_str(&format!(
            "| {}{} | {} | {} | {} / {} | {} | {} | {} | {} | {} | {} | {} | {:.1}% | {:.1}% | {:.1}% | {:.1}% | {:.1}% | {:.2} |\n",
            p.setting.name,
            if front.contains(&i) { " *" } else { "" },
            p.setting.views,
            p.setting.max_cluster_points,
            p.setting.min_cluster_size,
            p.setting.min_samples,
            p.setting.model.trim_end_matches(".toml"),
            window.map_or(0, |w| w.count / rounds as u64),
            window.map_or("no window".to_owned(), |w| format!(
                "{:.0} / {:.0}",
                w.p50_ms, w.p99_ms
            )),
            ms(Stage::Model),
            ms(Stage::Group),
            ms(Stage::Semantics),
            ms(Stage::Fusion),
            100.0 * s.recall_at_25,
            100.0 * s.recall_at_50,
            100.0 * s.precision,
            100.0 * s.duplicate_rate,
            100.0 * s.name_top1,
            s.id_switches_per_100_sightings,
        ));
    }
    md.push_str(&format!("\nReproduce: `{reproduce} --out DIR`.\n"));
    md
}

/// Recall@0.25 against window p50 (log scale), every setting labelled, the Pareto front joined.
fn pareto_chart(path: &Path, points: &[Point]) -> Result<()> {
    use plotters::prelude::*;
    let finite: Vec<&Point> = points
        .iter()
        .filter(|p| p.window_p50().is_finite() && p.window_p50() > 0.0)
        .collect();
    let x0 = finite
        .iter()
        .map(|p| p.window_p50())
        .fold(f64::INFINITY, f64::min)
        .min(50.0);
    let x1 = finite
        .iter()
        .map(|p| p.window_p50())
        .fold(0.0f64, f64::max)
        .max(200.0);
    let err = |e: &dyn std::fmt::Display| anyhow::anyhow!("{e}");
    let root = SVGBackend::new(path, (760, 460)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption("What accuracy costs in time", ("sans-serif", 20))
        .margin(14)
        .x_label_area_size(42)
        .y_label_area_size(52)
        .build_cartesian_2d((x0 * 0.8..x1 * 1.25).log_scale(), 0.0..100.0)
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .light_line_style(WHITE)
        .x_desc("window -> map update, p50 (ms, log scale)")
        .y_desc("map recall@0.25 (%)")
        .draw()
        .map_err(|e| err(&e))?;
    let front: Vec<(f64, f64)> = pareto_front(points)
        .into_iter()
        .map(|i| {
            (
                points[i].window_p50(),
                100.0 * points[i].scored.total.summary().recall_at_25,
            )
        })
        .collect();
    chart
        .draw_series(LineSeries::new(front, BLUE.stroke_width(2)))
        .map_err(|e| err(&e))?;
    for p in finite {
        let xy = (
            p.window_p50(),
            100.0 * p.scored.total.summary().recall_at_25,
        );
        let colour = if p.setting.name == "default" {
            RED
        } else {
            BLACK
        };
        chart
            .draw_series(std::iter::once(Circle::new(xy, 4, colour.filled())))
            .map_err(|e| err(&e))?;
        chart
            .draw_series(std::iter::once(Text::new(
                p.setting.name.clone(),
                xy,
                ("sans-serif", 13).into_font(),
            )))
            .map_err(|e| err(&e))?;
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}
