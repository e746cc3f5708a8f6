//! The model runtime against Python onnxruntime: the reconstruction-contract fixture gives the same
//! outputs on the same inputs, its manifest is enforced, and lifting yields valid Gaussians.
//! Needs the ONNX Runtime library that `make setup` installs (PyPI onnxruntime 1.31.1 in .venv).

#![allow(clippy::unwrap_used)] // test helpers outside #[test] functions unwrap too

use std::path::{Path, PathBuf};

use groupforward::frame::{DepthImage, RgbImage};
use groupforward::model::manifest::Manifest;
use groupforward::model::reconstruction::{Geometry, ModelInputs, ReconstructionModel, View};
use groupforward::model::{init_runtime, ModelError, SessionOptions};
use groupforward::recon::camera::Camera;
use groupforward::recon::Rigid;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/fixtures")
}

fn load_fixture() -> ReconstructionModel {
    init_runtime(None).unwrap_or_else(|e| panic!("{e}"));
    ReconstructionModel::load(
        &fixtures().join("recon_contract.toml"),
        &SessionOptions::default(),
    )
    .unwrap()
}

fn floats(v: &serde_json::Value) -> Vec<f32> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap() as f32)
        .collect()
}

#[test]
fn fixture_outputs_equal_python_onnxruntime() {
    let mut model = load_fixture();
    let reference: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(fixtures().join("recon_contract.reference.json")).unwrap(),
    )
    .unwrap();
    let shape = &reference["inputs"]["images"]["shape"];
    let (views, height, width) = (
        shape[1].as_u64().unwrap() as usize,
        shape[3].as_u64().unwrap() as usize,
        shape[4].as_u64().unwrap() as usize,
    );
    let images = floats(&reference["inputs"]["images"]["data"]);
    let points = floats(&reference["inputs"]["points"]["data"]);
    let inputs = ModelInputs {
        views,
        height,
        width,
        images,
        geometry: Geometry::Points(points),
    };
    let prediction = model.run_tensors(inputs).unwrap();
    for (name, got) in [
        ("depth", &prediction.depth),
        ("gaussians", &prediction.gaussians),
        ("embeddings", &prediction.embeddings),
    ] {
        let expected = floats(&reference["outputs"][name]["data"]);
        assert_eq!(got.len(), expected.len(), "{name}");
        let worst = got
            .iter()
            .zip(&expected)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst <= 1e-6, "{name}: max difference {worst}");
    }
}

#[test]
fn views_become_world_gaussians_through_the_runner() {
    let mut model = load_fixture();
    let rgb = RgbImage {
        width: 12,
        height: 8,
        data: (0..12 * 8 * 3).map(|i| (i % 251) as u8).collect(),
    };
    let depth = DepthImage {
        width: 12,
        height: 8,
        metres: vec![2.0; 96],
    };
    let camera = Camera::pinhole(12, 8, 10.0, 10.0, 5.5, 3.5).unwrap();
    let views: Vec<View> = (0..3)
        .map(|i| View {
            rgb: &rgb,
            depth: Some(&depth),
            camera,
            world_from_camera: Rigid::new(
                glam::DQuat::IDENTITY,
                glam::DVec3::new(0.1 * f64::from(i), 0.0, 0.0),
            ),
        })
        .collect();
    let prediction = model.predict(&views).unwrap();
    assert_eq!(
        (prediction.views, prediction.height, prediction.width),
        (3, 4, 6)
    );
    let gaussians = model.to_gaussians(&prediction, &views).unwrap();
    gaussians.validate().unwrap();
    assert_eq!(gaussians.len(), 3 * 4 * 6);
    assert_eq!(gaussians.embedding_dim, 8);
    // The fixture's depth is the centred point z plus half the mean colour: positive here.
    assert!(gaussians.means.iter().all(|m| m.z > 0.0));
    // Missing depth for an RGB-D model is an input error, not a panic.
    let no_depth = [View {
        depth: None,
        ..views[0]
    }];
    assert!(matches!(
        model.predict(&no_depth),
        Err(ModelError::Input(_))
    ));
    assert!(matches!(model.predict(&[]), Err(ModelError::Input(_))));
}

#[test]
fn a_manifest_that_disagrees_with_the_graph_is_a_clear_error() {
    init_runtime(None).unwrap_or_else(|e| panic!("{e}"));
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(
        fixtures().join("recon_contract.onnx"),
        dir.path().join("recon_contract.onnx"),
    )
    .unwrap();
    let manifest = std::fs::read_to_string(fixtures().join("recon_contract.toml")).unwrap();
    let wrong = manifest
        .replace(
            "shape = [1, \"V\", 8, \"H\", \"W\"]",
            "shape = [1, \"V\", 16, \"H\", \"W\"]",
        )
        .replace("name = \"points\"", "name = \"xyz\"");
    std::fs::write(dir.path().join("wrong.toml"), wrong).unwrap();
    let err = ReconstructionModel::load(&dir.path().join("wrong.toml"), &SessionOptions::default())
        .unwrap_err();
    let text = err.to_string();
    assert!(matches!(err, ModelError::ContractMismatch { .. }), "{text}");
    assert!(text.contains("input `xyz` is missing"), "{text}");
    assert!(
        text.contains("input `points` is in the graph but not in the manifest"),
        "{text}"
    );
    assert!(
        text.contains("output `embeddings` axis 2 is 8, expected 16"),
        "{text}"
    );
    let missing_file = manifest.replace("file = \"recon_contract.onnx\"", "file = \"nope.onnx\"");
    std::fs::write(dir.path().join("missing.toml"), missing_file).unwrap();
    assert!(matches!(
        ReconstructionModel::load(&dir.path().join("missing.toml"), &SessionOptions::default()),
        Err(ModelError::ModelNotFound(_))
    ));
    // A mode whose inputs the graph does not take: the runner could not feed it.
    let posed = manifest.replace("mode = \"rgbd\"", "mode = \"rgb_posed\"");
    std::fs::write(dir.path().join("posed.toml"), posed).unwrap();
    let err = ReconstructionModel::load(&dir.path().join("posed.toml"), &SessionOptions::default())
        .unwrap_err();
    let text = err.to_string();
    assert!(matches!(err, ModelError::ContractMismatch { .. }), "{text}");
    assert!(
        text.contains("takes an input `world_from_camera`; the graph has none"),
        "{text}"
    );
    assert!(text.contains("input `points` is not one"), "{text}");
    std::fs::write(dir.path().join("bad.toml"), "name = 3").unwrap();
    assert!(matches!(
        Manifest::load(&dir.path().join("bad.toml")),
        Err(ModelError::Manifest { .. })
    ));
}
