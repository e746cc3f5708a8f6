//! `groupforward eval window`: windows of sim scenes no training saw through the node's window
//! pass, scored as the paper scores a feed-forward pass. Writes `DIR/windows.csv` (one row per
//! window), `DIR/summary.json` and `DIR/summary.md`, and prints the table.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use groupforward::eval::window::{phrase_index, score_scene, WindowEval, WindowScore};
use groupforward::group::semantics::OTHER_PHRASE;
use groupforward::recon::metrics::semantic_scores;
use groupforward::window::WindowModels;
use groupforward_sim::scene::SceneFile;
use groupforward_sim::simulation::Simulation;

use crate::eval::{eval_config, model_hash};
use crate::sim::progress_bar;

/// Means of one group of windows (NaN-free: windows without a score are left out of its mean).
#[derive(Debug, Clone, Copy, Default, serde::Serialize)]
pub struct Means {
    pub windows: usize,
    pub depth_abs_rel: f64,
    pub depth_delta1: f64,
    pub ari: f64,
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
        semantic_pixel_accuracy: mean(|r| r.semantic_pixel_accuracy),
        novel_psnr: mean(|r| r.novel_psnr),
        novel_ssim: mean(|r| r.novel_ssim),
        novel_semantic_pixel_accuracy: mean(|r| r.novel_semantic_pixel_accuracy),
    }
}

pub fn eval_window(
    files: &[SceneFile],
    model: Option<PathBuf>,
    windows: usize,
    out: &Path,
) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let config = eval_config(model);
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
        "scene,frames,novel_frame,instances,depth_abs_rel,depth_delta1,ari,semantic_pixel_accuracy,novel_psnr,novel_ssim,novel_semantic_pixel_accuracy"
    )?;
    for r in &eval.rows {
        let frames: Vec<String> = r.frames.iter().map(usize::to_string).collect();
        writeln!(
            csv,
            "{},{},{},{},{:.5},{:.5},{:.5},{:.5},{:.3},{:.5},{:.5}",
            r.scene,
            frames.join(" "),
            r.novel_frame,
            r.instances,
            r.depth_abs_rel,
            r.depth_delta1,
            r.ari,
            r.semantic_pixel_accuracy,
            r.novel_psnr,
            r.novel_ssim,
            r.novel_semantic_pixel_accuracy
        )?;
    }
    csv.flush()?;

    let all = means(&eval.rows.iter().collect::<Vec<_>>());
    let per_scene: Vec<(String, Means)> = files
        .iter()
        .map(|f| {
            let rows: Vec<&WindowScore> = eval.rows.iter().filter(|r| r.scene == f.name).collect();
            (f.name.clone(), means(&rows))
        })
        .collect();
    // mIoU over every scored pixel of the run (per-window mIoU over a handful of classes is noise).
    let miou = |labels: &groupforward::eval::window::PooledLabels| -> Option<f64> {
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
    let table = markdown(&per_scene, &all, source_miou, novel_miou);
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
        "| scene | windows | depth abs-rel | δ<1.25 | instance ARI | semantic pixel acc. | novel PSNR (dB) | novel SSIM | novel semantic pixel acc. |\n\
         | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n",
    );
    let row = |name: &str, m: &Means| {
        format!(
            "| {name} | {} | {:.3} | {:.1}% | {:.3} | {:.1}% | {:.2} | {:.3} | {:.1}% |\n",
            m.windows,
            m.depth_abs_rel,
            100.0 * m.depth_delta1,
            m.ari,
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
