//! `groupforward model-check`: load an ONNX model and check it against its manifest.

use std::path::PathBuf;

use anyhow::Result;
use groupforward::model::manifest::Manifest;
use groupforward::model::{init_runtime, open_session, SessionOptions};

#[derive(Debug, clap::Args)]
pub struct ModelCheckArgs {
    /// The model's manifest, `models/<name>.toml`.
    manifest: PathBuf,
    /// ONNX Runtime library to load (default: `ORT_DYLIB_PATH`, then the project's `.venv`).
    #[arg(long)]
    onnxruntime: Option<PathBuf>,
}

pub fn run(args: ModelCheckArgs) -> Result<()> {
    let library = init_runtime(args.onnxruntime.as_deref())?;
    let loaded = Manifest::load(&args.manifest)?;
    let session = open_session(&loaded.model_path(), &SessionOptions::default())?;
    loaded.check(&session)?;
    println!(
        "{}: {} matches its manifest ({:?}{}; ONNX Runtime {})",
        args.manifest.display(),
        loaded.model_path().display(),
        loaded.kind,
        if loaded.fixture { ", test fixture" } else { "" },
        library.display()
    );
    Ok(())
}
