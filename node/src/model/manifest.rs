//! Model manifests (`models/<name>.toml`): file, contract (input / output names and shapes),
//! normalisation, provenance, license and benchmark figures. A loaded graph is checked against its
//! manifest before use.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{ModelError, Result};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ModelKind {
    Reconstruction,
    Semantic,
    TextEncoder,
}

/// What a reconstruction model takes: RGB plus world points from sensor depth, RGB only, or RGB
/// with every view's intrinsics and TF pose (a plane sweep across the views inside the model).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InputMode {
    Rgbd,
    Rgb,
    RgbPosed,
}

impl InputMode {
    /// The input tensors a model of this mode takes besides `images`.
    pub fn geometry_inputs(self) -> &'static [&'static str] {
        match self {
            Self::Rgbd => &["points"],
            Self::Rgb => &[],
            Self::RgbPosed => &["intrinsics", "world_from_camera"],
        }
    }
}

/// One dimension: a fixed size, or a named dynamic one (`"V"`, `"H"`, `"W"`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Dim {
    Fixed(i64),
    Named(String),
}

/// Element type of a tensor in the contract.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum DType {
    #[default]
    F32,
    I64,
}

impl DType {
    fn matches(self, ty: ort::value::TensorElementType) -> bool {
        matches!(
            (self, ty),
            (Self::F32, ort::value::TensorElementType::Float32)
                | (Self::I64, ort::value::TensorElementType::Int64)
        )
    }
}

#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TensorSpec {
    pub name: String,
    pub shape: Vec<Dim>,
    #[serde(default)]
    pub dtype: DType,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Normalization {
    pub image_mean: [f32; 3],
    pub image_std: [f32; 3],
    /// World points are divided by this after centring on the window's mean camera position.
    #[serde(default = "one")]
    pub points_scale: f32,
}

fn one() -> f32 {
    1.0
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub name: String,
    pub kind: ModelKind,
    /// Test fixtures are never used by the node outside tests.
    #[serde(default)]
    pub fixture: bool,
    /// ONNX file, relative to the manifest.
    pub file: PathBuf,
    pub mode: Option<InputMode>,
    pub input_height: Option<usize>,
    pub input_width: Option<usize>,
    pub embedding_dim: Option<usize>,
    /// Tokenizer file (text encoders), relative to the manifest.
    pub tokenizer: Option<PathBuf>,
    /// Longest token sequence; longer texts are truncated (text encoders).
    pub max_tokens: Option<usize>,
    pub provenance: String,
    pub license: String,
    pub normalization: Option<Normalization>,
    pub inputs: Vec<TensorSpec>,
    pub outputs: Vec<TensorSpec>,
    #[serde(default)]
    pub benchmarks: BTreeMap<String, f64>,
    /// Where the manifest was read from (set on load).
    #[serde(skip)]
    pub dir: PathBuf,
}

impl Manifest {
    pub fn load(path: &Path) -> Result<Self> {
        let err = |reason: String| ModelError::Manifest {
            path: path.to_owned(),
            reason,
        };
        let text = std::fs::read_to_string(path).map_err(|e| err(e.to_string()))?;
        let mut manifest: Self = toml::from_str(&text).map_err(|e| err(e.to_string()))?;
        manifest.dir = path.parent().map(Path::to_owned).unwrap_or_default();
        if manifest.kind == ModelKind::Reconstruction {
            for required in ["images", "depth", "gaussians", "embeddings"] {
                let present = manifest
                    .inputs
                    .iter()
                    .chain(&manifest.outputs)
                    .any(|t| t.name == required);
                if !present {
                    return Err(err(format!(
                        "a reconstruction model needs a `{required}` tensor"
                    )));
                }
            }
            if manifest.mode.is_none() {
                return Err(err(
                    "a reconstruction model must say its `mode` (rgbd, rgb or rgb_posed)".into(),
                ));
            }
        }
        Ok(manifest)
    }

    pub fn model_path(&self) -> PathBuf {
        self.dir.join(&self.file)
    }

    /// Compare the graph's inputs and outputs with the manifest: names, ranks, fixed sizes, types;
    /// and a reconstruction model's inputs with its mode's.
    pub fn check(&self, session: &ort::session::Session) -> Result<()> {
        let mut problems = Vec::new();
        compare("input", &self.inputs, session.inputs(), &mut problems);
        compare("output", &self.outputs, session.outputs(), &mut problems);
        if let Some(mode) = self.mode.filter(|_| self.kind == ModelKind::Reconstruction) {
            mode_problems(mode, session.inputs(), &mut problems);
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(ModelError::ContractMismatch {
                model: self.name.clone(),
                problems,
            })
        }
    }
}

/// The runner feeds a reconstruction model exactly the inputs its mode names; a graph that takes
/// others could not run.
fn mode_problems(mode: InputMode, actual: &[ort::value::Outlet], problems: &mut Vec<String>) {
    let fed: Vec<&str> = std::iter::once("images")
        .chain(mode.geometry_inputs().iter().copied())
        .collect();
    for name in &fed {
        if !actual.iter().any(|o| o.name() == *name) {
            problems.push(format!(
                "a {mode:?} model takes an input `{name}`; the graph has none"
            ));
        }
    }
    for outlet in actual {
        if !fed.contains(&outlet.name()) {
            problems.push(format!(
                "input `{}` is not one a {mode:?} model is fed",
                outlet.name()
            ));
        }
    }
}

fn compare(
    what: &str,
    expected: &[TensorSpec],
    actual: &[ort::value::Outlet],
    problems: &mut Vec<String>,
) {
    for spec in expected {
        let Some(outlet) = actual.iter().find(|o| o.name() == spec.name) else {
            let names: Vec<&str> = actual.iter().map(|o| o.name()).collect();
            problems.push(format!(
                "{what} `{}` is missing (the graph has {names:?})",
                spec.name
            ));
            continue;
        };
        match outlet.dtype() {
            ort::value::ValueType::Tensor { ty, shape, .. } => {
                if !spec.dtype.matches(*ty) {
                    problems.push(format!(
                        "{what} `{}` is {ty:?}, expected {:?}",
                        spec.name, spec.dtype
                    ));
                }
                let dims: Vec<i64> = shape.iter().copied().collect();
                if dims.len() != spec.shape.len() {
                    problems.push(format!(
                        "{what} `{}` has rank {} ({dims:?}), expected {} ({:?})",
                        spec.name,
                        dims.len(),
                        spec.shape.len(),
                        spec.shape
                    ));
                    continue;
                }
                for (axis, (got, want)) in dims.iter().zip(&spec.shape).enumerate() {
                    if let Dim::Fixed(size) = want {
                        if *got >= 0 && got != size {
                            problems.push(format!(
                                "{what} `{}` axis {axis} is {got}, expected {size}",
                                spec.name
                            ));
                        }
                    }
                }
            }
            other => problems.push(format!("{what} `{}` is not a tensor: {other:?}", spec.name)),
        }
    }
    for outlet in actual {
        if !expected.iter().any(|s| s.name == outlet.name()) {
            problems.push(format!(
                "{what} `{}` is in the graph but not in the manifest",
                outlet.name()
            ));
        }
    }
}
