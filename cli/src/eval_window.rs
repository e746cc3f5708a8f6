//! `groupforward eval window`: windows of sim scenes no training saw through the node's window
//! pass, scored as the paper scores a feed-forward pass. Writes `DIR/windows.csv` (one row per
//! window), `DIR/summary.json` and `DIR/summary.md`, and prints the table.

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result};
use groupforward::group::semantics::OTHER_PHRASE;
use groupforward::recon::metrics::semantic_scores;
use groupforward::window::WindowModels;
use groupforward_harness::eval::window::{
    phrase_index, score_scene, CoveredObject, WindowEval, WindowScore, COVERAGE_MIN_PIXELS,
};
use groupforward_sim::scene::SceneFile;
use groupforward_sim::simulation::Simulation;

use crate::eval::{eval_config, model_hash};
use crate::eval_command::ModelArgs;
use crate::sim::progress_bar;

/// Means of one group of windows (NaN-free: windows without a score are left out of its mean).
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct Means {
    pub windows: usize,
    pub depth_abs_rel: f64,
    pub depth_delta1: f64,
    pub ari: f64,
    pub object_coverage: f64,
    pub semantic_pixel_accuracy: f64,
    pub novel_psnr: f64,
    pub novel_ssim: f64,
    pub novel_semantic_pixel_accuracy: f64,
}

fn means(rows: &[&WindowScore]) -> Means {
    let mean = |value: fn(&WindowScore) -> f64| {
        let finite: Vec<f64> = rows
            .iter()
            .map(|r| value(r))
            .filter(|v| v.is_finite())
            .collect();
        finite.iter().sum::<f64>() / finite.len().max(1) as f64
    };
    Means {
        windows: rows.len(),
        depth_abs_rel: mean(|r| r.depth_abs_rel),
        depth_delta1: mean(|r| r.depth_delta1),
        ari: mean(|r| r.ari),
        object_coverage: mean(|r| r.object_coverage),
        semantic_pixel_accuracy: mean(|r| r.semantic_pixel_accuracy),
        novel_psnr: mean(|r| r.novel_psnr),
        novel_ssim: mean(|r| r.novel_ssim),
        novel_semantic_pixel_accuracy: mean(|r| r.novel_semantic_pixel_accuracy),
    }
}

pub fn eval_window(
    files: &[SceneFile],
    models: &ModelArgs,
    windows: usize,
    out: &Path,
) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let config = eval_config(models)?;
    let views = config.window.views;
    let mut models = WindowModels::load(&config.models, &config.semantics)
        .context("loading the models (`make setup` installs ONNX Runtime)")?;
    let bar = progress_bar(files.len() as u64, "scoring windows");
    let mut eval = WindowEval::default();
    for file in files {
        bar.set_message(file.name.clone());
        let sim = Simulation::new(file.clone()).with_context(|| format!("scene {}", file.name))?;
        score_scene(&sim, &file.name, &mut models, windows, views, &mut eval)
            .with_context(|| format!("scene {}", file.name))?;
        bar.inc(1);
    }
    bar.finish_and_clear();

    let mut csv = std::io::BufWriter::new(std::fs::File::create(out.join("windows.csv"))?);
    writeln!(
        csv,
        "scene,frames,novel_frame,instances,depth_abs_rel,depth_delta1,ari,object_coverage,semantic_pixel_accuracy,novel_psnr,novel_ssim,novel_semantic_pixel_accuracy"
    )?;
    for r in &eval.rows {
        let frames: Vec<String> = r.frames.iter().map(usize::to_string).collect();
        writeln!(
            csv,
            "{},{},{},{},{:.5},{:.5},{:.5},{:.5},{:.5},{:.3},{:.5},{:.5}",
            r.scene,
            frames.join(" "),
            r.novel_frame,
            r.instances,
            r.depth_abs_rel,
            r.depth_delta1,
            r.ari,
            r.object_coverage,
            r.semantic_pixel_accuracy,
            r.novel_psnr,
            r.novel_ssim,
            r.novel_semantic_pixel_accuracy
        )?;
    }
    csv.flush()?;
    let mut objects_csv = std::io::BufWriter::new(std::fs::File::create(out.join("objects.csv"))?);
    writeln!(
        objects_csv,
        "scene,class,object,pixels,best_iou,in_best,split,to_structure,unassigned,impurity"
    )?;
    for o in &eval.objects {
        let c = &o.coverage;
        writeln!(
            objects_csv,
            "{},{},{},{},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4}",
            o.scene,
            o.class,
            c.object,
            c.pixels,
            c.best_iou,
            c.in_best,
            c.split,
            c.to_structure,
            c.unassigned,
            c.impurity
        )?;
    }
    objects_csv.flush()?;
    let coverage = coverage_rows(&eval.objects);

    let all = means(&eval.rows.iter().collect::<Vec<_>>());
    let per_scene: Vec<(String, Means)> = files
        .iter()
        .map(|f| {
            let rows: Vec<&WindowScore> = eval.rows.iter().filter(|r| r.scene == f.name).collect();
            (f.name.clone(), means(&rows))
        })
        .collect();
    // mIoU over every scored pixel of the run (per-window mIoU over a handful of classes is noise).
    let miou = |labels: &groupforward_harness::eval::window::PooledLabels| -> Option<f64> {
        let vocabulary = models.vocabulary.as_ref()?;
        let other = phrase_index(vocabulary, OTHER_PHRASE);
        semantic_scores(
            &labels.predicted,
            &labels.truth,
            vocabulary.phrases.len(),
            other,
            None,
        )
        .ok()
        .map(|s| s.miou)
    };
    let (source_miou, novel_miou) = (miou(&eval.source_labels), miou(&eval.novel_labels));
    let reconstruction = config.models.reconstruction.clone().unwrap_or_default();
    let semantic = config.models.semantic.clone().unwrap_or_default();
    let json = serde_json::json!({
        "summary": all,
        "object_pixels": coverage.iter().map(|(class, c)| serde_json::json!({"class": class, "coverage": c})).collect::<Vec<_>>(),
        "source_semantic_miou": source_miou,
        "novel_semantic_miou": novel_miou,
        "lpips": "not computed: it needs pretrained network weights, which cannot be fetched here",
        "scenes": per_scene.iter().map(|(name, m)| serde_json::json!({"scene": name, "summary": m})).collect::<Vec<_>>(),
        "models": {
            "reconstruction": reconstruction.display().to_string(),
            "reconstruction_sha256": model_hash(&reconstruction)?,
            "semantic_sha256": model_hash(&semantic)?,
        },
        "config": {
            "views": views,
            "windows_per_scene": windows,
            "grouping": format!("{:?}", models.grouping),
            "novel_view": "halfway between the first two context views, rendered at the model resolution from the window's instance Gaussians",
        },
    });
    std::fs::write(
        out.join("summary.json"),
        serde_json::to_string_pretty(&json)?,
    )?;
    let mut table = markdown(&per_scene, &all, source_miou, novel_miou);
    table.push_str(&coverage_markdown(&coverage));
    std::fs::write(out.join("summary.md"), &table)?;
    print!("{table}");
    println!(
        "LPIPS is not computed (it needs pretrained weights); wrote {}",
        out.display()
    );
    Ok(())
}

fn markdown(
    per_scene: &[(String, Means)],
    all: &Means,
    source_miou: Option<f64>,
    novel_miou: Option<f64>,
) -> String {
    let mut out = String::from(
        "| scene | windows | depth abs-rel | δ<1.25 | instance ARI | object coverage | semantic pixel acc. | novel PSNR (dB) | novel SSIM | novel semantic pixel acc. |\n\
         | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n",
    );
    let row = |name: &str, m: &Means| {
        format!(
            "| {name} | {} | {:.3} | {:.1}% | {:.3} | {:.3} | {:.1}% | {:.2} | {:.3} | {:.1}% |\n",
            m.windows,
            m.depth_abs_rel,
            100.0 * m.depth_delta1,
            m.ari,
            m.object_coverage,
            100.0 * m.semantic_pixel_accuracy,
            m.novel_psnr,
            m.novel_ssim,
            100.0 * m.novel_semantic_pixel_accuracy,
        )
    };
    for (name, m) in per_scene {
        out.push_str(&row(name, m));
    }
    out.push_str(&row("**all**", all));
    let pct = |v: Option<f64>| v.map_or("-".to_owned(), |v| format!("{:.1}%", 100.0 * v));
    out.push_str(&format!(
        "\nsemantic mIoU over every scored pixel: source views {}, novel views {}\n",
        pct(source_miou),
        pct(novel_miou)
    ));
    out
}

/// Where objects' pixels went, pooled over one class's sightings (an object in one window).
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct CoverageMeans {
    pub sightings: usize,
    pub best_iou: f64,
    pub in_best: f64,
    pub split: f64,
    pub to_structure: f64,
    pub unassigned: f64,
    pub impurity: f64,
}

/// Per class (most sighted first), then `all`.
fn coverage_rows(objects: &[CoveredObject]) -> Vec<(String, CoverageMeans)> {
    let pool = |of: &[&CoveredObject]| {
        let n = of.len().max(1) as f64;
        let mean = |value: fn(&CoveredObject) -> f64| of.iter().map(|o| value(o)).sum::<f64>() / n;
        CoverageMeans {
            sightings: of.len(),
            best_iou: mean(|o| o.coverage.best_iou),
            in_best: mean(|o| o.coverage.in_best),
            split: mean(|o| o.coverage.split),
            to_structure: mean(|o| o.coverage.to_structure),
            unassigned: mean(|o| o.coverage.unassigned),
            impurity: mean(|o| o.coverage.impurity),
        }
    };
    let mut classes: Vec<&str> = objects.iter().map(|o| o.class.as_str()).collect();
    classes.sort_unstable();
    classes.dedup();
    let mut rows: Vec<(String, CoverageMeans)> = classes
        .into_iter()
        .map(|class| {
            let of: Vec<&CoveredObject> = objects.iter().filter(|o| o.class == class).collect();
            (class.to_owned(), pool(&of))
        })
        .collect();
    rows.sort_by(|a, b| b.1.sightings.cmp(&a.1.sightings).then(a.0.cmp(&b.0)));
    rows.push((
        "**all**".to_owned(),
        pool(&objects.iter().collect::<Vec<_>>()),
    ));
    rows
}

fn coverage_markdown(rows: &[(String, CoverageMeans)]) -> String {
    let mut out = format!(
        "\nWhere objects' pixels went (objects with ≥ {COVERAGE_MIN_PIXELS} model pixels in a window; \
         shares of the object's pixels; impurity: the best instance's pixels that are not the object):\n\n\
         | class | sightings | best IoU | in best instance | split off | to the room | in no instance | impurity |\n\
         | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n"
    );
    for (class, c) in rows {
        out.push_str(&format!(
            "| {class} | {} | {:.3} | {:.1}% | {:.1}% | {:.1}% | {:.1}% | {:.1}% |\n",
            c.sightings,
            c.best_iou,
            100.0 * c.in_best,
            100.0 * c.split,
            100.0 * c.to_structure,
            100.0 * c.unassigned,
            100.0 * c.impurity,
        ));
    }
    out
}
