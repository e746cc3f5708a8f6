//! The shipped text encoder against sentence-transformers: token ids equal Python's, embeddings are
//! close (cosine ≥ 0.98 each) and give the same nearest neighbours. Reference data:
//! node/tests/reference/text_encoder.json, written by train/export_text_encoder.py.

#![allow(clippy::unwrap_used)] // test helpers outside #[test] functions unwrap too

use std::path::Path;

use groupforward::model::text::{cosine, TextEncoder};
use groupforward::model::{init_runtime, SessionOptions};

fn encoder() -> TextEncoder {
    init_runtime(None).unwrap_or_else(|e| panic!("{e}"));
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/all-MiniLM-L6-v2.toml");
    TextEncoder::load(&manifest, &SessionOptions::default()).unwrap()
}

fn reference() -> Vec<(String, Vec<u32>, Vec<f32>)> {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../node/tests/reference/text_encoder.json");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    json["cases"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            let ids = c["token_ids"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_u64().unwrap() as u32)
                .collect();
            let embedding = c["sentence_transformers"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap() as f32)
                .collect();
            (c["phrase"].as_str().unwrap().to_owned(), ids, embedding)
        })
        .collect()
}

fn nearest(i: usize, embeddings: &[Vec<f32>]) -> usize {
    (0..embeddings.len())
        .filter(|&j| j != i)
        .max_by(|&a, &b| {
            cosine(&embeddings[i], &embeddings[a])
                .total_cmp(&cosine(&embeddings[i], &embeddings[b]))
        })
        .unwrap()
}

#[test]
fn token_ids_equal_the_python_tokenizer() {
    let encoder = encoder();
    for (phrase, ids, _) in reference() {
        assert_eq!(encoder.token_ids(&phrase).unwrap(), ids, "{phrase}");
    }
}

#[test]
fn embeddings_match_sentence_transformers() {
    let mut encoder = encoder();
    let cases = reference();
    assert!(cases.len() >= 20);
    let mut ours = Vec::new();
    for (phrase, _, expected) in &cases {
        let embedding = encoder.embed(phrase).unwrap();
        assert_eq!(embedding.len(), 384);
        let norm = embedding.iter().map(|v| v * v).sum::<f32>().sqrt();
        assert!((norm - 1.0).abs() < 1e-3, "{phrase}: norm {norm}");
        let c = cosine(&embedding, expected);
        assert!(c >= 0.98, "{phrase}: cosine {c}");
        ours.push(embedding);
    }
    let theirs: Vec<Vec<f32>> = cases.iter().map(|c| c.2.clone()).collect();
    let agree = (0..cases.len())
        .filter(|&i| nearest(i, &ours) == nearest(i, &theirs))
        .count();
    assert!(
        agree * 10 >= cases.len() * 9,
        "nearest neighbours agree for {agree} of {}",
        cases.len()
    );
    // Open vocabulary: a synonym is closer to its object than to other objects.
    let can = encoder.embed("garbage can").unwrap();
    assert!(
        cosine(&can, &encoder.embed("trash bin").unwrap())
            > cosine(&can, &encoder.embed("sofa").unwrap())
    );
}

#[test]
fn long_inputs_are_truncated_not_rejected_and_repeats_come_from_the_cache() {
    let mut encoder = encoder();
    let long = "chair ".repeat(1000);
    assert_eq!(encoder.token_ids(&long).unwrap().len(), 256);
    let first = encoder.embed(&long).unwrap();
    assert_eq!(encoder.embed(&long).unwrap(), first);
    assert!(encoder.embed("").unwrap().iter().all(|v| v.is_finite()));
}
