//! The text encoder runner: a phrase in, one L2-normalised embedding out (all-MiniLM-L6-v2, D = 384,
//! with mean pooling and normalisation inside the ONNX graph). Tokenisation is the `tokenizers` crate
//! on the model's own tokenizer.json, without padding and truncated as sentence-transformers does.

use std::collections::{HashMap, VecDeque};
use std::path::Path;

use super::manifest::{Manifest, ModelKind};
use super::{open_session, ModelError, Result, SessionOptions};

/// Phrases whose embeddings are kept (queries repeat: "chair", "table", ...).
pub const CACHE_CAPACITY: usize = 1024;
const DEFAULT_MAX_TOKENS: usize = 256;

pub struct TextEncoder {
    session: ort::session::Session,
    tokenizer: tokenizers::Tokenizer,
    pub manifest: Manifest,
    dim: usize,
    cache: HashMap<String, Vec<f32>>,
    order: VecDeque<String>,
}

impl std::fmt::Debug for TextEncoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "TextEncoder({}, {} cached)",
            self.manifest.name,
            self.cache.len()
        )
    }
}

impl TextEncoder {
    pub fn load(manifest_path: &Path, options: &SessionOptions) -> Result<Self> {
        let manifest = Manifest::load(manifest_path)?;
        let manifest_err = |reason: String| ModelError::Manifest {
            path: manifest_path.to_owned(),
            reason,
        };
        if manifest.kind != ModelKind::TextEncoder {
            return Err(manifest_err(format!(
                "kind is {:?}, not text_encoder",
                manifest.kind
            )));
        }
        let tokenizer_file = manifest
            .tokenizer
            .as_ref()
            .map(|t| manifest.dir.join(t))
            .ok_or_else(|| manifest_err("a text encoder needs a `tokenizer` file".into()))?;
        let mut tokenizer = tokenizers::Tokenizer::from_file(&tokenizer_file)
            .map_err(|e| manifest_err(format!("tokenizer {}: {e}", tokenizer_file.display())))?;
        // The shipped tokenizer.json pads to 128; sentence-transformers pads nothing and truncates.
        tokenizer.with_padding(None);
        tokenizer
            .with_truncation(Some(tokenizers::TruncationParams {
                max_length: manifest.max_tokens.unwrap_or(DEFAULT_MAX_TOKENS),
                ..Default::default()
            }))
            .map_err(|e| manifest_err(format!("tokenizer truncation: {e}")))?;
        let session = open_session(&manifest.model_path(), options)?;
        manifest.check(&session)?;
        let dim = manifest
            .embedding_dim
            .ok_or_else(|| manifest_err("a text encoder needs `embedding_dim`".into()))?;
        Ok(Self {
            session,
            tokenizer,
            manifest,
            dim,
            cache: HashMap::new(),
            order: VecDeque::new(),
        })
    }

    /// Forget every cached embedding (benchmarks measure the cold path with it).
    pub fn clear_cache(&mut self) {
        self.cache.clear();
        self.order.clear();
    }

    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Token ids as the model sees them (with [CLS] / [SEP]).
    pub fn token_ids(&self, text: &str) -> Result<Vec<u32>> {
        let encoding = self
            .tokenizer
            .encode(text, true)
            .map_err(|e| ModelError::Input(format!("cannot tokenise {text:?}: {e}")))?;
        Ok(encoding.get_ids().to_vec())
    }

    /// The embedding of `text` (cached).
    pub fn embed(&mut self, text: &str) -> Result<Vec<f32>> {
        if let Some(hit) = self.cache.get(text) {
            return Ok(hit.clone());
        }
        let ids: Vec<i64> = self.token_ids(text)?.into_iter().map(i64::from).collect();
        let len = ids.len();
        let input_ids = ort::value::Tensor::from_array(([1usize, len], ids))?;
        let attention_mask = ort::value::Tensor::from_array(([1usize, len], vec![1i64; len]))?;
        let outputs = self
            .session
            .run(ort::inputs!["input_ids" => input_ids, "attention_mask" => attention_mask])?;
        let (_, data) = outputs
            .get("embedding")
            .ok_or_else(|| ModelError::Ort("output `embedding` missing".into()))?
            .try_extract_tensor::<f32>()?;
        if data.len() != self.dim || !data.iter().all(|v| v.is_finite()) {
            return Err(ModelError::Ort(format!(
                "embedding of {} values (expected {} finite values)",
                data.len(),
                self.dim
            )));
        }
        let embedding = data.to_vec();
        if self.order.len() >= CACHE_CAPACITY {
            if let Some(oldest) = self.order.pop_front() {
                self.cache.remove(&oldest);
            }
        }
        self.order.push_back(text.to_owned());
        self.cache.insert(text.to_owned(), embedding.clone());
        Ok(embedding)
    }
}

/// Cosine similarity; 0 when either vector is zero.
pub fn cosine(a: &[f32], b: &[f32]) -> f32 {
    let dot: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
    let na = a.iter().map(|x| x * x).sum::<f32>().sqrt();
    let nb = b.iter().map(|x| x * x).sum::<f32>().sqrt();
    if na == 0.0 || nb == 0.0 {
        0.0
    } else {
        dot / (na * nb)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cosine_of_zero_vectors_is_zero_not_nan() {
        assert_eq!(cosine(&[0.0, 0.0], &[1.0, 0.0]), 0.0);
        assert!((cosine(&[1.0, 1.0], &[2.0, 2.0]) - 1.0).abs() < 1e-6);
    }
}
