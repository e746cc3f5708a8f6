//! The semantic model runner (LSeg role, ARCHITECTURE.md §5): one image in, dense features in the text
//! encoder's embedding space out, so a pixel's (or an instance prototype's) cosine to a phrase's
//! text embedding scores the phrase.
//!
//! Contract: `image` f32 [1,3,H,W] in [0,1] (normalised as the manifest says) → `features`
//! [1,D,H/s,W/s], D = the manifest's `embedding_dim` (the text encoder's, 384 for MiniLM).

use std::path::Path;

use super::manifest::{Manifest, ModelKind};
use super::reconstruction::model_image;
use super::{open_session, ModelError, Result, SessionOptions};
use crate::frame::RgbImage;

/// Dense features of one image, channel after channel as the model gives them (pooling reads
/// them so, and a transpose cost a third of the semantic stage):
/// `data[c * width * height + y * width + x]`.
#[derive(Debug, Clone, PartialEq)]
pub struct DenseFeatures {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl DenseFeatures {
    /// The feature vector of pixel `y * width + x`.
    pub fn at(&self, pixel: usize) -> Vec<f32> {
        let plane = self.width * self.height;
        (0..self.channels)
            .map(|c| self.data[c * plane + pixel])
            .collect()
    }
}

/// A loaded semantic model.
pub struct SemanticModel {
    session: ort::session::Session,
    pub manifest: Manifest,
}

impl std::fmt::Debug for SemanticModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "SemanticModel({})", self.manifest.name)
    }
}

impl SemanticModel {
    /// Load the model a manifest describes and check the graph against the manifest.
    pub fn load(manifest_path: &Path, options: &SessionOptions) -> Result<Self> {
        let manifest = Manifest::load(manifest_path)?;
        let reason = if manifest.kind != ModelKind::Semantic {
            Some(format!("kind is {:?}, not semantic", manifest.kind))
        } else if manifest.input_width.is_none() || manifest.input_height.is_none() {
            Some("a semantic model needs input_width and input_height".to_owned())
        } else if manifest.embedding_dim.is_none() {
            Some("a semantic model needs embedding_dim (its feature channels)".to_owned())
        } else {
            None
        };
        if let Some(reason) = reason {
            return Err(ModelError::Manifest {
                path: manifest_path.to_owned(),
                reason,
            });
        }
        let session = open_session(&manifest.model_path(), options)?;
        manifest.check(&session)?;
        Ok(Self { session, manifest })
    }

    /// Feature channels D.
    pub fn channels(&self) -> usize {
        self.manifest.embedding_dim.unwrap_or(0)
    }

    /// Features of one image (resized to the model's input size).
    pub fn features(&mut self, image: &RgbImage) -> Result<DenseFeatures> {
        if image.width == 0
            || image.height == 0
            || image.data.len() != (image.width * image.height * 3) as usize
        {
            return Err(ModelError::Input(
                "colour image size does not match its data".into(),
            ));
        }
        let (width, height) = (
            self.manifest.input_width.unwrap_or(0),
            self.manifest.input_height.unwrap_or(0),
        );
        let planar = model_image(image, width, height, self.manifest.normalization.as_ref());
        let channels = self.channels();
        let input = ort::value::Tensor::from_array(([1usize, 3, height, width], planar))?;
        let outputs = self.session.run(ort::inputs!["image" => input])?;
        let value = outputs
            .get("features")
            .ok_or_else(|| ModelError::Ort("output `features` missing".into()))?;
        let (shape, data) = value.try_extract_tensor::<f32>()?;
        let dims: Vec<i64> = shape.iter().copied().collect();
        let (h, w) = match dims[..] {
            [1, c, h, w] if c as usize == channels && h > 0 && w > 0 => (h as usize, w as usize),
            _ => {
                return Err(ModelError::Ort(format!(
                    "output `features` has shape {dims:?}, expected [1, {channels}, h, w]"
                )))
            }
        };
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            return Err(ModelError::Ort(format!(
                "output `features` has a non-finite value at {i}"
            )));
        }
        Ok(DenseFeatures {
            width: w,
            height: h,
            channels,
            data: data.to_vec(),
        })
    }
}
