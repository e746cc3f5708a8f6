//! `groupforward eval`'s subcommands: which scenes they replay, and the dispatch to each
//! evaluation (`map` in `eval.rs`, `window`, `refer`, `all` in their own files).

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Subcommand;

use crate::eval::{eval_config, eval_map, scene_files};
use groupforward_sim::scene::SceneFile;

/// Which scenes an evaluation replays, and with which effects.
#[derive(Debug, Clone, clap::Args)]
pub struct ScenesArgs {
    /// Procedural split to score (its scenes are disjoint from training's).
    #[arg(long, default_value = "benchmark")]
    split: String,
    #[arg(long, default_value_t = 10)]
    scenes: u64,
    #[arg(long, default_value_t = 0)]
    first_index: u64,
    /// Score these scene files (or `<split>:<index>` specs) instead of a split (repeatable).
    #[arg(long)]
    scene: Vec<String>,
    /// Replace every scene's effects by a preset: `clean`, `realistic`, `dropout:<p>`, or
    /// `realistic:<effect>,...` (only those of realistic's effects).
    #[arg(long)]
    effects: Option<String>,
}

/// Which models and settings an evaluation runs (default: the shipped models, the built-in settings).
#[derive(Debug, Clone, Default, clap::Args)]
pub struct ModelArgs {
    /// Reconstruction model manifest (default: the shipped RGB-D model).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Semantic model manifest (default: the shipped Semantic-mini), e.g. a candidate written by
    /// `train/export_semantic.py`, to be paired with the shipped one through `--against`.
    #[arg(long)]
    pub semantic_model: Option<PathBuf>,
    /// A node config file (YAML, as `groupforward run --config` reads it) to score instead of the
    /// built-in defaults: its window, grouping, fusion, semantics and refer settings, and its
    /// models (paths relative to the working directory), unless `--model` or `--semantic-model`
    /// name others. Its cameras and transport are not used.
    #[arg(long)]
    pub config: Option<PathBuf>,
}

impl ModelArgs {
    pub fn reconstruction(model: Option<PathBuf>) -> Self {
        Self {
            model,
            ..Self::default()
        }
    }
}

impl ScenesArgs {
    fn files(&self) -> Result<Vec<SceneFile>> {
        scene_files(
            &self.split,
            self.first_index,
            self.scenes,
            &self.scene,
            self.effects.as_deref(),
        )
    }
}

#[derive(Debug, Subcommand)]
pub enum EvalCommand {
    /// The persistent map against ground truth: recall at 3D IoU 0.25 / 0.5, precision,
    /// duplicates, merged objects, names, room instances, identity switches; and the same
    /// yardstick on the window instances before fusion.
    Map {
        #[command(flatten)]
        scenes: ScenesArgs,
        #[command(flatten)]
        models: ModelArgs,
        /// An earlier run's output directory over the same scenes: also print the paired
        /// difference of the headline figures with its 95% interval (is a change beyond the
        /// spread between scenes?).
        #[arg(long)]
        against: Option<PathBuf>,
        #[arg(long, default_value = "target/eval/map")]
        out: PathBuf,
    },
    /// Single windows as a feed-forward pass is scored: depth abs-rel and δ<1.25 of the model's
    /// depth, instance ARI, semantic pixel accuracy and mIoU in the source views, and PSNR, SSIM
    /// and semantic labels in a novel view rendered from the window's instances (LPIPS is not
    /// computed: it needs pretrained weights).
    Window {
        #[command(flatten)]
        scenes: ScenesArgs,
        #[command(flatten)]
        models: ModelArgs,
        /// Windows per scene, spread over its trajectory.
        #[arg(long, default_value_t = 2)]
        windows: usize,
        #[arg(long, default_value = "target/eval/window")]
        out: PathBuf,
    },
    /// Every evaluation on the same scenes (`window`, `map`, `refer`, each into DIR/<name>), then
    /// one table of their headline figures and DIR/summary.json.
    All {
        #[command(flatten)]
        scenes: ScenesArgs,
        /// Windows per scene for `window`.
        #[arg(long, default_value_t = 2)]
        windows: usize,
        #[arg(long, default_value = "target/eval/all")]
        out: PathBuf,
    },
    /// Referring: each scene replayed through the node's stages, then the scene's generated
    /// expressions (or `--expressions`) asked through the `Refer` service's handler; selection
    /// accuracy, top-K recall, Acc@0.25 / 0.5, by relation, easy / hard, view-dependent or not,
    /// and query latency.
    Refer {
        #[command(flatten)]
        scenes: ScenesArgs,
        /// JSON lines of the sim's expression records (`scene`, `text`, `targets`, ...) to ask
        /// instead of the generated ones; only lines whose `scene` is replayed are asked.
        #[arg(long)]
        expressions: Option<PathBuf>,
        #[command(flatten)]
        models: ModelArgs,
        /// Also answer the single-target expressions without instances (the paper's ablation:
        /// semantic features lifted per voxel, the target phrase's voxels boxed) and compare.
        #[arg(long)]
        baseline: bool,
        /// Write every answer's evidence bundle (PNG + JSON) here.
        #[arg(long)]
        evidence: Option<PathBuf>,
        /// `builtin` or `vlm` (needs `--vlm-endpoint`); default: the config's (`builtin`).
        #[arg(long)]
        reasoner: Option<String>,
        /// OpenAI-compatible API base URL for `--reasoner vlm`, e.g. http://localhost:8000/v1
        /// (default: the config's).
        #[arg(long)]
        vlm_endpoint: Option<String>,
        #[arg(long)]
        vlm_model: Option<String>,
        #[arg(long, default_value = "target/eval/refer")]
        out: PathBuf,
    },
}

pub fn run(command: EvalCommand) -> Result<()> {
    match command {
        EvalCommand::Map {
            scenes,
            models,
            against,
            out,
        } => eval_map(
            &scenes.files()?,
            &models,
            scenes.effects.as_deref(),
            against.as_deref(),
            &out,
        ),
        EvalCommand::Window {
            scenes,
            models,
            windows,
            out,
        } => crate::eval_window::eval_window(&scenes.files()?, &models, windows, &out),
        EvalCommand::All {
            scenes,
            windows,
            out,
        } => {
            std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
            crate::eval_all::eval_all(&scenes.files()?, scenes.effects.as_deref(), windows, &out)
        }
        EvalCommand::Refer {
            scenes,
            expressions,
            models,
            baseline,
            evidence,
            reasoner,
            vlm_endpoint,
            vlm_model,
            out,
        } => {
            let files = scenes.files()?;
            let mut config = eval_config(&models)?;
            // What the command line names replaces the config's.
            if let Some(reasoner) = reasoner {
                config.refer.reasoner = reasoner;
            }
            if let Some(endpoint) = vlm_endpoint {
                config.refer.vlm.endpoint = endpoint;
            }
            if let Some(model) = vlm_model {
                config.refer.vlm.model = model;
            }
            if let Some(evidence) = evidence {
                config.refer.evidence_dir = evidence.display().to_string();
            }
            crate::eval_refer::eval_refer(&files, &config, expressions.as_deref(), baseline, &out)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::shipped_models;

    #[test]
    fn a_named_semantic_model_replaces_only_the_shipped_semantic_model() {
        let candidate = PathBuf::from("/tmp/candidate/semantic.toml");
        let config = eval_config(&ModelArgs {
            semantic_model: Some(candidate.clone()),
            ..ModelArgs::default()
        })
        .unwrap();
        assert_eq!(config.models.semantic, Some(candidate));
        assert_eq!(
            config.models.reconstruction,
            Some(shipped_models().join("groupforward-mini-rgbd.toml"))
        );
        let shipped = eval_config(&ModelArgs::default()).unwrap();
        assert_eq!(
            shipped.models.semantic,
            Some(shipped_models().join("semantic-mini.toml"))
        );
    }

    #[test]
    fn a_config_file_is_scored_with_its_own_settings_and_models_unless_the_command_names_others() {
        let dir = tempfile::tempdir().expect("a temporary directory");
        let path = dir.path().join("robot.yaml");
        std::fs::write(
            &path,
            "window:\n  min_rotation_deg: 5.0\nmodels:\n  semantic: my/semantic.toml\n",
        )
        .unwrap();
        let args = ModelArgs {
            config: Some(path.clone()),
            ..ModelArgs::default()
        };
        let config = eval_config(&args).unwrap();
        assert_eq!(config.window.min_rotation_deg, 5.0);
        assert_eq!(
            config.models.semantic,
            Some(PathBuf::from("my/semantic.toml"))
        );
        let candidate = PathBuf::from("/tmp/candidate/semantic.toml");
        let config = eval_config(&ModelArgs {
            semantic_model: Some(candidate.clone()),
            ..args
        })
        .unwrap();
        assert_eq!(config.models.semantic, Some(candidate));
        assert_eq!(config.window.min_rotation_deg, 5.0);
        // A mistake names the file.
        std::fs::write(&path, "window:\n  min_rotation_degs: 5.0\n").unwrap();
        let error = eval_config(&ModelArgs {
            config: Some(path),
            ..ModelArgs::default()
        })
        .unwrap_err();
        assert!(format!("{error:#}").contains("robot.yaml"), "{error:#}");
    }
}
