//! Vocabulary files: the classes instances are named with and, with each class, what the map may
//! assume of its objects (typical and smallest depth, largest side, whether they stand on the
//! floor). A user edits the file like the class names; a class without priors gets the map's
//! class-agnostic behaviour. The built-in default (`node/data/default_vocabulary.yaml`) lists the
//! classes the shipped semantic model was trained on, with priors measured on the simulator's
//! training rooms by `groupforward sim vocabulary`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// What walls, floor and anything unnamed are called (the semantic model's explicit `other` class).
pub const OTHER_PHRASE: &str = "other";

/// Something longer than this many times a class's largest side is not one of its objects: two
/// of them side by side would be as long. Read on benchmark 0-19: at 1.5, instances a little
/// longer than their object (a chair with a piece of the table it stands at, 0.8-0.9 m; a lamp
/// with its stand) lost their right name; tables and desks named box, chair or sink measured 2.2
/// to 2.4 times those names' largest sides.
pub const NAME_LENGTH_MARGIN: f64 = 2.0;

/// Something taller than this many times a class's tallest object is not one of its objects: two
/// of them stacked would be as tall. The same margin as the length's, for the same reason; read on
/// benchmark 13200-13219 (a chair named box, 0.99 m tall; 1.5 answered every expression alike) and
/// 14000-14019, checked on 14200-14219 and layouts 820-839 (history.md, Referring).
pub const NAME_HEIGHT_MARGIN: f64 = 2.0;

/// Something shorter across than this share of a class's smallest depth is not one of its
/// objects: even the shorter side of the smallest of them is longer (a trash bin 0.4 m across,
/// seen by four windows, named sofa; no sofa is less than 0.77 m deep). A piece of a larger object
/// is smaller too, so the name gives way only where the names that admit the size hold their share
/// ([`crate::group::semantics::MIN_ADMITTED_SHARE`]). Read on benchmark 14400-14419 (three trash
/// bins named sofa); checked on 14200-14219 and layouts 820-839, fresh 14600-14619 and layouts
/// 860-879 (history.md, Referring).
pub const NAME_SMALLEST_SHARE: f64 = 0.6;

/// An instance's size as measured from its points (m): its longer horizontal side and its
/// height. A side that is no number (not measured) rules out no name.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasuredSize {
    pub length_m: f64,
    pub height_m: f64,
}

/// The default vocabulary file, compiled in. Generated from the simulator by `groupforward sim
/// vocabulary`; the harness's tests keep the two in sync.
pub const DEFAULT_VOCABULARY_YAML: &str = include_str!("../../data/default_vocabulary.yaml");

#[derive(Debug, thiserror::Error)]
pub enum VocabularyError {
    #[error("vocabulary file {0}: {1}")]
    Read(PathBuf, std::io::Error),
    /// serde_yaml_ng's message names the line and column.
    #[error("vocabulary file {0}: {1}")]
    Parse(String, serde_yaml_ng::Error),
    #[error("vocabulary file {0}: class {1:?}: {2}")]
    Invalid(String, String, String),
}

/// A vocabulary file: its classes in order ([`OTHER_PHRASE`] is not one: the node adds it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VocabularyFile {
    pub classes: Vec<VocabularyClass>,
}

/// One class of a vocabulary file: its name and the priors the map may use for its objects.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VocabularyClass {
    pub name: String,
    /// The depth (shorter horizontal side, m) its objects typically have: a face seen from one
    /// side is completed to it. Only for objects with flat faces; round ones have none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub typical_depth_m: Option<f64>,
    /// The smallest depth its objects have: a face with a wall closer behind it is the object's
    /// back, and the object stands in front of it; something narrower across than
    /// [`NAME_SMALLEST_SHARE`] of it is not one of them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub smallest_depth_m: Option<f64>,
    /// The length (longer horizontal side, m) its objects typically have: an object seen in
    /// part grows to it along its length where no camera saw past its end. Only for objects
    /// with flat faces, like the depth.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub typical_length_m: Option<f64>,
    /// The longest horizontal side its objects have: touching pieces named alike fold only while
    /// together they are not much longer.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub largest_side_m: Option<f64>,
    /// The tallest its objects are (m): something much taller is not one of them, whatever its
    /// colours say (a chair the features call a box).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tallest_m: Option<f64>,
    /// Its objects stand on the floor: a box seen floating above it reaches down to it.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub stands_on_floor: bool,
    /// The height (m) its objects typically have, for classes that rest on something other than
    /// the floor: a box seen much shorter (a lamp's shade without its stand) grows down toward
    /// it, no lower than the surface under it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub typical_height_m: Option<f64>,
    /// What one does with its objects ("sit on", "wash hands"): a query for "the thing you can
    /// X" finds the class whose functions (or name) the text encoder puts nearest X.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub functions: Vec<String>,
}

impl VocabularyFile {
    /// Parse a vocabulary file's text; `source` names it in errors. Every prior must be a
    /// positive length, and a smallest depth at most the typical one.
    pub fn parse(text: &str, source: &str) -> Result<Self, VocabularyError> {
        let file: Self = serde_yaml_ng::from_str(text)
            .map_err(|e| VocabularyError::Parse(source.to_owned(), e))?;
        for class in &file.classes {
            let invalid = |why: &str| {
                VocabularyError::Invalid(source.to_owned(), class.name.clone(), why.to_owned())
            };
            if class.name.trim().is_empty() || class.name == OTHER_PHRASE {
                return Err(invalid("a class needs a name other than `other`"));
            }
            if class.functions.iter().any(|f| f.trim().is_empty()) {
                return Err(invalid("a function must not be empty"));
            }
            let lengths = [
                class.typical_depth_m,
                class.smallest_depth_m,
                class.typical_length_m,
                class.largest_side_m,
                class.tallest_m,
                class.typical_height_m,
            ];
            if lengths
                .iter()
                .flatten()
                .any(|v| !(v.is_finite() && *v > 0.0))
            {
                return Err(invalid("priors are lengths in metres, positive and finite"));
            }
            if let (Some(smallest), Some(typical)) = (class.smallest_depth_m, class.typical_depth_m)
            {
                if smallest > typical {
                    return Err(invalid("smallest_depth_m exceeds typical_depth_m"));
                }
            }
        }
        Ok(file)
    }

    /// Read and parse the vocabulary file at `path`.
    pub fn load(path: &Path) -> Result<Self, VocabularyError> {
        let text =
            std::fs::read_to_string(path).map_err(|e| VocabularyError::Read(path.to_owned(), e))?;
        Self::parse(&text, &path.display().to_string())
    }

    /// The built-in default ([`DEFAULT_VOCABULARY_YAML`]).
    pub fn builtin() -> Self {
        // Compiled in, and a unit test parses it: it cannot fail at run time.
        Self::parse(DEFAULT_VOCABULARY_YAML, "(built in)")
            .unwrap_or_else(|e| panic!("the built-in default vocabulary does not parse: {e}"))
    }

    /// The phrases instances are named with: the classes' names, then [`OTHER_PHRASE`].
    pub fn phrases(&self) -> Vec<String> {
        self.classes
            .iter()
            .map(|c| c.name.clone())
            .chain([OTHER_PHRASE.to_owned()])
            .collect()
    }

    /// The classes' priors, by name.
    pub fn priors(&self) -> ClassPriors {
        ClassPriors(
            self.classes
                .iter()
                .map(|c| (c.name.clone(), c.clone()))
                .collect(),
        )
    }
}

/// The default vocabulary's phrases ([`DEFAULT_VOCABULARY_YAML`]).
pub fn default_vocabulary() -> Vec<String> {
    VocabularyFile::builtin().phrases()
}

/// What the map may assume of the objects of each name ([`VocabularyClass`]'s priors); a name
/// without an entry has none. Empty: class-agnostic everywhere.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ClassPriors(HashMap<String, VocabularyClass>);

impl ClassPriors {
    /// The built-in default vocabulary's priors.
    pub fn builtin() -> Self {
        VocabularyFile::builtin().priors()
    }

    fn class(&self, name: &str) -> Option<&VocabularyClass> {
        self.0.get(name)
    }

    /// The typical depth of `name`'s objects, if it has one.
    pub fn typical_depth(&self, name: &str) -> Option<f64> {
        self.class(name)?.typical_depth_m
    }

    /// The smallest depth `name`'s objects have, if known.
    pub fn smallest_depth(&self, name: &str) -> Option<f64> {
        self.class(name)?.smallest_depth_m
    }

    /// The typical length of `name`'s objects, if it has one.
    pub fn typical_length(&self, name: &str) -> Option<f64> {
        self.class(name)?.typical_length_m
    }

    /// The longest horizontal side `name`'s objects have, if known.
    pub fn largest_side(&self, name: &str) -> Option<f64> {
        self.class(name)?.largest_side_m
    }

    /// Whether something `length_m` long (its longer horizontal side, as measured) could be one
    /// of `name`'s objects: at most [`NAME_LENGTH_MARGIN`] times its largest side (any length
    /// when the class has none, or the length is no number).
    pub fn admits_length(&self, name: &str, length_m: f64) -> bool {
        unknown_or(length_m, self.largest_side(name), |side| {
            length_m <= NAME_LENGTH_MARGIN * side
        })
    }

    /// The tallest `name`'s objects are, if known.
    pub fn tallest(&self, name: &str) -> Option<f64> {
        self.class(name)?.tallest_m
    }

    /// Whether something `height_m` tall could be one of `name`'s objects: at most
    /// [`NAME_HEIGHT_MARGIN`] times its tallest (any height when the class has none, or the
    /// height is no number).
    pub fn admits_height(&self, name: &str, height_m: f64) -> bool {
        unknown_or(height_m, self.tallest(name), |tallest| {
            height_m <= NAME_HEIGHT_MARGIN * tallest
        })
    }

    /// Whether something `length_m` long (its longer horizontal side, as measured) is not too
    /// small across to be one of `name`'s objects: at least [`NAME_SMALLEST_SHARE`] of their
    /// smallest depth (any length when the class has none, or the length is no number).
    pub fn admits_small_length(&self, name: &str, length_m: f64) -> bool {
        unknown_or(length_m, self.smallest_depth(name), |depth| {
            length_m >= NAME_SMALLEST_SHARE * depth
        })
    }

    /// Whether an instance of `size` could be one of `name`'s objects: its length, neither too
    /// long nor too short ([`ClassPriors::admits_length`], [`ClassPriors::admits_small_length`]),
    /// and its height ([`ClassPriors::admits_height`]).
    pub fn admits_size(&self, name: &str, size: MeasuredSize) -> bool {
        self.admits_length(name, size.length_m)
            && self.admits_small_length(name, size.length_m)
            && self.admits_height(name, size.height_m)
    }

    /// The typical height of `name`'s objects, if it has one (classes that do not stand on the
    /// floor).
    pub fn typical_height(&self, name: &str) -> Option<f64> {
        self.class(name)?.typical_height_m
    }

    /// Whether `name`'s objects stand on the floor (false when unknown).
    pub fn stands_on_floor(&self, name: &str) -> bool {
        self.class(name).is_some_and(|c| c.stands_on_floor)
    }

    /// What one does with `name`'s objects (none when unknown).
    pub fn functions(&self, name: &str) -> &[String] {
        self.class(name).map_or(&[], |c| c.functions.as_slice())
    }
}

/// Whether a `measured` side passes `check` against a class's `prior`: it does when either is
/// unknown (a side that is no number was not measured; a class without the prior rules out
/// nothing), the admission rules' common ground.
fn unknown_or(measured: f64, prior: Option<f64>, check: impl FnOnce(f64) -> bool) -> bool {
    !measured.is_finite() || prior.is_none_or(check)
}

/// Where a node's vocabulary file comes from: a path, or the built-in default.
pub fn load_vocabulary_file(path: Option<&Path>) -> Result<VocabularyFile, VocabularyError> {
    match path {
        Some(path) => VocabularyFile::load(path),
        None => Ok(VocabularyFile::builtin()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_vocabulary_file_parses_to_named_classes_and_other_last() {
        let phrases = default_vocabulary();
        assert!(phrases.len() > 1);
        assert_eq!(phrases.last().map(String::as_str), Some(OTHER_PHRASE));
        assert!(phrases[..phrases.len() - 1]
            .iter()
            .all(|p| !p.trim().is_empty() && p != OTHER_PHRASE));
    }

    #[test]
    fn a_vocabulary_file_with_an_unknown_field_is_refused() {
        let text = "classes:\n  - name: whiteboard\n    colour: white\n";
        let error = VocabularyFile::parse(text, "mine.yaml")
            .map(|_| ())
            .unwrap_err();
        let message = error.to_string();
        assert!(
            message.contains("mine.yaml") && message.contains("line"),
            "{message}"
        );
    }

    #[test]
    fn priors_that_are_no_lengths_are_refused_with_the_class_named() {
        for bad in [
            "typical_depth_m: -0.4",
            "largest_side_m: .nan",
            "typical_length_m: 0",
            "typical_height_m: -0.5",
            "tallest_m: .inf",
            "typical_depth_m: 0.3\n    smallest_depth_m: 0.5",
        ] {
            let text = format!("classes:\n  - name: crate\n    {bad}\n");
            let message = VocabularyFile::parse(&text, "mine.yaml")
                .map(|_| ())
                .unwrap_err()
                .to_string();
            assert!(message.contains("\"crate\""), "{bad}: {message}");
        }
    }

    #[test]
    fn classes_without_priors_have_none_and_unknown_names_neither() {
        let text = "classes:\n  - name: whiteboard\n    functions: [write on]\n  - name: coat rack\n    stands_on_floor: true\n    largest_side_m: 0.6\n";
        let priors = VocabularyFile::parse(text, "mine.yaml")
            .map(|f| f.priors())
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(priors.typical_depth("whiteboard"), None);
        assert!(!priors.stands_on_floor("whiteboard"));
        assert!(priors.stands_on_floor("coat rack"));
        assert_eq!(priors.largest_side("coat rack"), Some(0.6));
        assert_eq!(priors.largest_side("fire extinguisher"), None);
        assert_eq!(priors.typical_length("coat rack"), None);
        assert_eq!(priors.typical_height("whiteboard"), None);
        assert_eq!(priors.functions("whiteboard"), ["write on"]);
        assert!(priors.functions("coat rack").is_empty());
        assert_eq!(ClassPriors::default().smallest_depth("chair"), None);
    }
}
