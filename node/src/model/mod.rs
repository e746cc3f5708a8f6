//! Model runtime (ARCHITECTURE.md §5): ONNX models through `ort` with a dynamically loaded ONNX Runtime.
//!
//! The ONNX Runtime shared library comes from the PyPI `onnxruntime` wheel (nothing is downloaded by
//! the build). It is found by, in order: the config key, `ORT_DYLIB_PATH`, the project-local venv that
//! `make setup` installs. Each model has a manifest (`models/<name>.toml`) that the loaded graph is
//! checked against, so a wrong export is a clear error instead of garbage output.

pub mod manifest;
pub mod reconstruction;
pub mod semantic;
pub mod text;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use serde::{Deserialize, Serialize};

/// The ONNX Runtime version the project pins (PyPI `onnxruntime`), matching `ort` 2.0.0-rc.15.
pub const ONNXRUNTIME_VERSION: &str = "1.31.1";
/// How to install the library the node looks for.
pub const INSTALL_HINT: &str =
    "run `make setup` (installs PyPI onnxruntime==1.31.1 into .venv), or set `ORT_DYLIB_PATH` / the config's `onnxruntime` path to libonnxruntime.so";

pub const DEFAULT_TEXT_ENCODER: &str = "models/all-MiniLM-L6-v2.toml";
pub const DEFAULT_RECONSTRUCTION: &str = "models/groupforward-mini-rgbd.toml";
pub const DEFAULT_SEMANTIC: &str = "models/semantic-mini.toml";
pub const DEFAULT_MODEL_THREADS: usize = 2;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelsSection {
    /// ONNX Runtime library; null: `ORT_DYLIB_PATH`, then the project's `.venv` (`make setup`).
    pub onnxruntime: Option<std::path::PathBuf>,
    /// Execution provider: cpu, cuda or tensorrt (GPU providers need the matching cargo feature).
    pub provider: Provider,
    /// ONNX Runtime intra-op threads per model.
    pub threads: usize,
    /// Let ONNX Runtime's idle intra-op threads spin for work. Off: on a small machine the
    /// spinning threads of two models take the cores from the stages that follow a model pass
    /// (on 2 cores the window pass took 15% longer with it on; `groupforward bench sweep`).
    pub intra_op_spinning: bool,
    /// Text encoder manifest (relative paths resolve against the working directory).
    pub text_encoder: std::path::PathBuf,
    /// Reconstruction model manifest; `null` or a missing file: ingest only, no instances.
    pub reconstruction: Option<std::path::PathBuf>,
    /// Semantic model manifest (features per pixel, pooled into one prototype per instance);
    /// `null` or a missing file: instances are unnamed and associate by geometry alone.
    pub semantic: Option<std::path::PathBuf>,
}

impl Default for ModelsSection {
    fn default() -> Self {
        Self {
            onnxruntime: None,
            provider: Provider::Cpu,
            threads: DEFAULT_MODEL_THREADS,
            intra_op_spinning: false,
            text_encoder: DEFAULT_TEXT_ENCODER.into(),
            reconstruction: Some(DEFAULT_RECONSTRUCTION.into()),
            semantic: Some(DEFAULT_SEMANTIC.into()),
        }
    }
}

impl ModelsSection {
    /// The default models with their manifests looked up in `dir` instead of `models/` of the
    /// working directory (the demo, `eval` and tests use the repository's `models/`).
    pub fn shipped_in(dir: &Path) -> Self {
        let under = |default: &str| dir.join(default.trim_start_matches("models/"));
        Self {
            text_encoder: under(DEFAULT_TEXT_ENCODER),
            reconstruction: Some(under(DEFAULT_RECONSTRUCTION)),
            semantic: Some(under(DEFAULT_SEMANTIC)),
            ..Self::default()
        }
    }

    pub fn session_options(&self) -> SessionOptions {
        SessionOptions {
            provider: self.provider,
            intra_threads: self.threads,
            intra_op_spinning: self.intra_op_spinning,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("ONNX Runtime library not found (looked in: {searched}); {INSTALL_HINT}")]
    LibraryNotFound { searched: String },
    #[error("cannot load ONNX Runtime from {path}: {reason}; {INSTALL_HINT}")]
    LibraryLoad { path: PathBuf, reason: String },
    #[error("model file {0} not found")]
    ModelNotFound(PathBuf),
    #[error("cannot read manifest {path}: {reason}")]
    Manifest { path: PathBuf, reason: String },
    #[error("model {model} does not match its manifest:\n  {}", .problems.join("\n  "))]
    ContractMismatch {
        model: String,
        problems: Vec<String>,
    },
    #[error("execution provider `{0}` is not available in this ONNX Runtime build")]
    ProviderUnavailable(String),
    #[error("unknown execution provider `{0}` (cpu, cuda, tensorrt)")]
    UnknownProvider(String),
    #[error("input: {0}")]
    Input(String),
    #[error("onnxruntime: {0}")]
    Ort(String),
}

pub type Result<T> = std::result::Result<T, ModelError>;

impl From<ort::Error> for ModelError {
    fn from(e: ort::Error) -> Self {
        Self::Ort(e.to_string())
    }
}

/// Where the project-local setup puts the library: `.venv/lib/python3.*/site-packages/onnxruntime/capi/`.
fn project_local_candidates(root: &Path) -> Vec<PathBuf> {
    let lib = root.join(".venv").join("lib");
    let Ok(entries) = std::fs::read_dir(&lib) else {
        return Vec::new();
    };
    let mut found = Vec::new();
    for entry in entries.flatten() {
        let capi = entry.path().join("site-packages/onnxruntime/capi");
        let Ok(files) = std::fs::read_dir(&capi) else {
            continue;
        };
        let mut libs: Vec<PathBuf> = files
            .flatten()
            .map(|f| f.path())
            .filter(|p| {
                p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.starts_with("libonnxruntime.so") && !n.contains("providers"))
            })
            .collect();
        libs.sort();
        found.extend(libs);
    }
    found
}

/// The library to load: `configured` if given, else `ORT_DYLIB_PATH` if set, else the project-local
/// venv (searched from the working directory, then from the source tree this binary was built from).
/// An explicit path that does not exist is an error, never a silent fall-back to another library.
pub fn find_library(configured: Option<&Path>) -> Result<PathBuf> {
    let explicit = configured.map(Path::to_owned).or_else(|| {
        std::env::var_os("ORT_DYLIB_PATH")
            .filter(|p| !p.is_empty())
            .map(PathBuf::from)
    });
    if let Some(path) = explicit {
        return if path.is_file() {
            Ok(path)
        } else {
            Err(ModelError::LibraryNotFound {
                searched: path.display().to_string(),
            })
        };
    }
    let roots = [
        std::env::current_dir().ok(),
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .parent()
            .map(Path::to_owned),
    ];
    let mut searched = Vec::new();
    for root in roots.into_iter().flatten() {
        if let Some(found) = project_local_candidates(&root)
            .into_iter()
            .find(|p| p.is_file())
        {
            return Ok(found);
        }
        searched.push(root.join(".venv").display().to_string());
    }
    Err(ModelError::LibraryNotFound {
        searched: searched.join(", "),
    })
}

/// Why loading ONNX Runtime failed, kept by the process's one attempt so that every later call
/// reports it as it happened (a missing library as missing, not as a load failure of "").
#[derive(Debug, Clone)]
enum RuntimeFailure {
    NotFound { searched: String },
    Load { path: PathBuf, reason: String },
}

impl From<&RuntimeFailure> for ModelError {
    fn from(failure: &RuntimeFailure) -> Self {
        match failure.clone() {
            RuntimeFailure::NotFound { searched } => ModelError::LibraryNotFound { searched },
            RuntimeFailure::Load { path, reason } => ModelError::LibraryLoad { path, reason },
        }
    }
}

static ENVIRONMENT: OnceLock<
    std::result::Result<(PathBuf, ort::environment::Environment), RuntimeFailure>,
> = OnceLock::new();

/// Load ONNX Runtime and create its environment, once per process (later calls return the first
/// outcome). Errors are values: a missing, wrong or too-old library never panics.
pub fn init_runtime(configured: Option<&Path>) -> Result<PathBuf> {
    runtime(configured).map(|(path, _)| path.clone())
}

fn runtime(configured: Option<&Path>) -> Result<&'static (PathBuf, ort::environment::Environment)> {
    let outcome = ENVIRONMENT.get_or_init(|| {
        let path = find_library(configured).map_err(|e| match e {
            ModelError::LibraryNotFound { searched } => RuntimeFailure::NotFound { searched },
            other => RuntimeFailure::Load {
                path: PathBuf::new(),
                reason: other.to_string(),
            },
        })?;
        let load_error = |reason: String| RuntimeFailure::Load {
            path: path.clone(),
            reason,
        };
        let builder = ort::init_from(&path).map_err(|e| load_error(e.to_string()))?;
        let environment = builder
            .with_name("groupforward")
            .build()
            .map_err(|e| load_error(e.to_string()))?;
        Ok((path, environment))
    });
    outcome.as_ref().map_err(ModelError::from)
}

/// Execution provider by name; `cpu` always works, others must be present in the loaded library.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Provider {
    #[default]
    Cpu,
    Cuda,
    Tensorrt,
}

impl std::str::FromStr for Provider {
    type Err = ModelError;

    fn from_str(name: &str) -> Result<Self> {
        match name.to_ascii_lowercase().as_str() {
            "cpu" => Ok(Self::Cpu),
            "cuda" => Ok(Self::Cuda),
            "tensorrt" | "trt" => Ok(Self::Tensorrt),
            other => Err(ModelError::UnknownProvider(other.to_owned())),
        }
    }
}

/// Session options every runner shares.
#[derive(Debug, Clone, PartialEq)]
pub struct SessionOptions {
    pub provider: Provider,
    pub intra_threads: usize,
    pub intra_op_spinning: bool,
}

impl Default for SessionOptions {
    fn default() -> Self {
        Self {
            provider: Provider::Cpu,
            intra_threads: 2,
            intra_op_spinning: false,
        }
    }
}

/// Open an ONNX session with `options`; a requested GPU provider that cannot register is an error,
/// not a silent fall-back to the CPU.
pub fn open_session(path: &Path, options: &SessionOptions) -> Result<ort::session::Session> {
    if !path.is_file() {
        return Err(ModelError::ModelNotFound(path.to_owned()));
    }
    let (_, environment) = runtime(None)?;
    let mut builder = ort::session::Session::builder(environment)?
        .with_intra_threads(options.intra_threads.max(1))
        .map_err(|e| ModelError::Ort(e.to_string()))?
        .with_intra_op_spinning(options.intra_op_spinning)
        .map_err(|e| ModelError::Ort(e.to_string()))?;
    let provider = match options.provider {
        Provider::Cpu => None,
        #[cfg(feature = "cuda")]
        Provider::Cuda => Some(ort::ep::CUDA::default().build().error_on_failure()),
        #[cfg(feature = "tensorrt")]
        Provider::Tensorrt => Some(ort::ep::TensorRT::default().build().error_on_failure()),
        #[allow(unreachable_patterns)] // reachable when a GPU feature is off
        other => {
            return Err(ModelError::ProviderUnavailable(format!(
                "{} (this binary was built without the `{}` cargo feature)",
                format!("{other:?}").to_lowercase(),
                format!("{other:?}").to_lowercase()
            )))
        }
    };
    if let Some(provider) = provider {
        builder = builder.with_execution_providers([provider]).map_err(|_| {
            ModelError::ProviderUnavailable(format!("{:?}", options.provider).to_lowercase())
        })?;
    }
    Ok(builder.commit_from_file(path)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_configured_path_that_does_not_exist_is_reported_with_the_install_hint() {
        let missing = Path::new("/nonexistent/libonnxruntime.so.1.31.1");
        let err = find_library(Some(missing)).unwrap_err().to_string();
        assert!(
            err.contains("/nonexistent/libonnxruntime.so.1.31.1") && err.contains("make setup"),
            "{err}"
        );
    }

    #[test]
    fn provider_names() {
        assert_eq!("CUDA".parse::<Provider>().unwrap(), Provider::Cuda);
        assert_eq!("trt".parse::<Provider>().unwrap(), Provider::Tensorrt);
        assert!(matches!(
            "npu".parse::<Provider>(),
            Err(ModelError::UnknownProvider(_))
        ));
    }
}
