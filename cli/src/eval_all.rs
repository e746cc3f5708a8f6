//! `groupforward eval all`: every evaluation on the same scenes (`window`, `map`, `refer`, each
//! into its own folder with its full output), then one table of their headline figures and
//! `DIR/summary.json` holding the three summaries, the scenes (the procedural split's seeds are
//! their indices) and the model hashes.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use groupforward_sim::scene::SceneFile;
use serde_json::Value;

use crate::eval::{eval_config, eval_map};
use crate::eval_command::ModelArgs;
use crate::eval_refer::eval_refer;
use crate::eval_window::eval_window;

pub fn eval_all(
    files: &[SceneFile],
    effects: Option<&str>,
    windows: usize,
    out: &Path,
) -> Result<()> {
    let part = |name: &str| -> PathBuf { out.join(name) };
    let shipped = ModelArgs::default();
    eval_window(files, &shipped, windows, &part("window"))?;
    eval_map(files, &shipped, effects, None, &part("map"))?;
    eval_refer(files, &eval_config(&shipped)?, None, false, &part("refer"))?;
    let read = |name: &str| -> Result<Value> {
        let path = part(name).join("summary.json");
        let text = std::fs::read_to_string(&path)
            .with_context(|| format!("reading {}", path.display()))?;
        Ok(serde_json::from_str(&text)?)
    };
    let (window, map, refer) = (read("window")?, read("map")?, read("refer")?);
    let figure = |v: &Value, path: &[&str]| -> f64 {
        path.iter()
            .fold(v, |v, key| &v[*key])
            .as_f64()
            .unwrap_or(f64::NAN)
    };
    let pct = |v: f64| format!("{:.1}%", 100.0 * v);
    let rows: Vec<(&str, &str, String)> = vec![
        (
            "window",
            "depth abs-rel",
            format!("{:.3}", figure(&window, &["summary", "depth_abs_rel"])),
        ),
        (
            "window",
            "depth δ<1.25",
            pct(figure(&window, &["summary", "depth_delta1"])),
        ),
        (
            "window",
            "instance ARI",
            format!("{:.3}", figure(&window, &["summary", "ari"])),
        ),
        (
            "window",
            "semantic pixel accuracy / mIoU, source views",
            format!(
                "{} / {}",
                pct(figure(&window, &["summary", "semantic_pixel_accuracy"])),
                pct(figure(&window, &["source_semantic_miou"]))
            ),
        ),
        (
            "window",
            "novel view PSNR / SSIM",
            format!(
                "{:.2} dB / {:.3}",
                figure(&window, &["summary", "novel_psnr"]),
                figure(&window, &["summary", "novel_ssim"])
            ),
        ),
        (
            "window",
            "semantic pixel accuracy / mIoU, novel views",
            format!(
                "{} / {}",
                pct(figure(
                    &window,
                    &["summary", "novel_semantic_pixel_accuracy"]
                )),
                pct(figure(&window, &["novel_semantic_miou"]))
            ),
        ),
        (
            "map",
            "recall@0.25 / recall@0.5",
            format!(
                "{} / {}",
                pct(figure(&map, &["summary", "recall_at_25"])),
                pct(figure(&map, &["summary", "recall_at_50"]))
            ),
        ),
        (
            "map",
            "precision / duplicates",
            format!(
                "{} / {}",
                pct(figure(&map, &["summary", "precision"])),
                pct(figure(&map, &["summary", "duplicate_rate"]))
            ),
        ),
        (
            "map",
            "names top-1",
            pct(figure(&map, &["summary", "name_top1"])),
        ),
        (
            "map",
            "id switches / 100 sightings",
            format!(
                "{:.2}",
                figure(&map, &["summary", "id_switches_per_100_sightings"])
            ),
        ),
        (
            "map",
            "window → map update p50 / p99",
            format!(
                "{:.0} / {:.0} ms",
                figure(&map, &["window_millis", "p50"]),
                figure(&map, &["window_millis", "p99"])
            ),
        ),
        (
            "refer",
            "selection accuracy",
            pct(figure(&refer, &["selection_accuracy"])),
        ),
        (
            "refer",
            "Acc@0.25 / Acc@0.5",
            format!(
                "{} / {}",
                pct(figure(&refer, &["acc_at_25"])),
                pct(figure(&refer, &["acc_at_50"]))
            ),
        ),
        (
            "refer",
            "referring mIoU",
            format!("{:.3}", figure(&refer, &["referring_miou"])),
        ),
        (
            "refer",
            "query p50 / p99",
            format!(
                "{:.1} / {:.1} ms",
                figure(&refer, &["query_p50_ms"]),
                figure(&refer, &["query_p99_ms"])
            ),
        ),
    ];
    let mut table = format!(
        "\n{} scene(s); LPIPS is not computed (it needs pretrained weights)\n\n| evaluation | figure | value |\n| --- | --- | ---: |\n",
        files.len()
    );
    for (evaluation, name, value) in &rows {
        table.push_str(&format!("| {evaluation} | {name} | {value} |\n"));
    }
    let json = serde_json::json!({
        "scenes": files.iter().map(|f| f.name.clone()).collect::<Vec<_>>(),
        "effects": effects.unwrap_or("as the scene files say"),
        "window": window,
        "map": map,
        "refer": refer,
    });
    std::fs::write(
        out.join("summary.json"),
        serde_json::to_string_pretty(&json)?,
    )?;
    std::fs::write(out.join("summary.md"), &table)?;
    print!("{table}");
    println!("wrote {}", out.display());
    Ok(())
}
