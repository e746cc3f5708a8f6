//! Parse a referring expression into what the retrieval and the reasoners need: the target
//! concept, how many instances the expression asks for, attributes, one relation and its anchor
//! concepts (ARCHITECTURE.md §2). Rule-based and deterministic: relation words from the Sr3D taxonomy,
//! superlatives, colour and size adjectives, cardinality words and function phrases ("the thing
//! you can wash hands"). Concepts stay phrases: the text encoder compares them with the map's
//! instances, so any words work; nothing here maps a word to a class.

use serde::{Deserialize, Serialize};

/// Expressions longer than this are refused rather than searched for meaning.
pub const MAX_EXPRESSION_CHARS: usize = 512;

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    #[error("empty expression")]
    Empty,
    #[error("expression of {0} characters (at most {MAX_EXPRESSION_CHARS})")]
    TooLong(usize),
    #[error("no object named in {0:?}")]
    NoTarget(String),
    #[error("{relation:?} needs {needed} anchor object(s) in {text:?}")]
    MissingAnchor {
        relation: Relation,
        needed: usize,
        text: String,
    },
}

/// How many instances the expression asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Count {
    /// "the chair", "a lamp".
    One,
    /// "both chairs", "the two boxes".
    Exactly(usize),
    /// "all the chairs", "the chairs".
    All,
}

/// Relations to anchors (Sr3D); left / right / front / behind are decided in a view.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Relation {
    Closest,
    Farthest,
    Above,
    Below,
    On,
    Supporting,
    Left,
    Right,
    Front,
    Behind,
    Between,
}

impl Relation {
    pub fn view_dependent(self) -> bool {
        matches!(
            self,
            Relation::Left | Relation::Right | Relation::Front | Relation::Behind
        )
    }

    pub fn anchors_needed(self) -> usize {
        if self == Relation::Between {
            2
        } else {
            1
        }
    }
}

/// Superlatives and size adjectives, decided among the instances of the target concept.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Superlative {
    Biggest,
    Smallest,
    Tallest,
    Highest,
    Lowest,
    Leftmost,
    Rightmost,
}

impl Superlative {
    pub fn view_dependent(self) -> bool {
        matches!(self, Superlative::Leftmost | Superlative::Rightmost)
    }
}

/// A parsed expression.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Query {
    pub text: String,
    /// The target concept: a noun phrase ("trash bin") or, for function phrases, what one does
    /// with it ("wash hands").
    pub target: String,
    /// The target was named by what it is for, not what it is.
    pub function: bool,
    pub count: Count,
    /// A colour word ("red").
    pub color: Option<String>,
    pub superlative: Option<Superlative>,
    pub relation: Option<Relation>,
    /// Anchor concepts: one for most relations, two for "between" (the same phrase twice for
    /// "between the two chairs"). For a two-hop anchor, its target concept.
    pub anchors: Vec<String>,
    /// A two-hop anchor: the anchor phrase is itself a referring expression ("the cabinet
    /// closest to *the chair farthest from the bed*"), answered first; its answer is the anchor.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub anchor_query: Option<Box<Query>>,
}

impl Query {
    pub fn view_dependent(&self) -> bool {
        self.relation.is_some_and(Relation::view_dependent)
            || self.superlative.is_some_and(Superlative::view_dependent)
    }
}

/// Colour words the parser recognises as attributes (their RGB lives with the reasoner).
pub const COLOR_WORDS: &[&str] = &[
    "red", "orange", "yellow", "green", "blue", "purple", "brown", "black", "white", "grey",
    "gray", "beige", "pink",
];

/// Relation phrases, longest first within each relation so "to the left of" wins over "left".
const RELATION_PHRASES: &[(&[&str], Relation)] = &[
    (&["closest", "to"], Relation::Closest),
    (&["nearest", "to"], Relation::Closest),
    (&["next", "to"], Relation::Closest),
    (&["close", "to"], Relation::Closest),
    (&["near"], Relation::Closest),
    (&["nearest"], Relation::Closest),
    (&["closest"], Relation::Closest),
    (&["beside"], Relation::Closest),
    (&["farthest", "from"], Relation::Farthest),
    (&["furthest", "from"], Relation::Farthest),
    (&["farthest"], Relation::Farthest),
    (&["furthest"], Relation::Farthest),
    (&["far", "from"], Relation::Farthest),
    (&["on", "top", "of"], Relation::On),
    (&["supported", "by"], Relation::On),
    (&["resting", "on"], Relation::On),
    (&["standing", "on"], Relation::On),
    (&["sitting", "on"], Relation::On),
    (&["lying", "on"], Relation::On),
    (&["on"], Relation::On),
    (&["supporting"], Relation::Supporting),
    (&["holding"], Relation::Supporting),
    (&["above"], Relation::Above),
    (&["over"], Relation::Above),
    (&["below"], Relation::Below),
    (&["under"], Relation::Below),
    (&["underneath"], Relation::Below),
    (&["beneath"], Relation::Below),
    (&["to", "the", "left", "of"], Relation::Left),
    (&["left", "of"], Relation::Left),
    (&["to", "the", "right", "of"], Relation::Right),
    (&["right", "of"], Relation::Right),
    (&["in", "front", "of"], Relation::Front),
    (&["behind"], Relation::Behind),
    (&["in", "back", "of"], Relation::Behind),
    (&["between"], Relation::Between),
];

/// Words that only join a relative clause ("the chair that is next to ...").
const FILLER: &[&str] = &[
    "that", "which", "is", "are", "who", "located", "placed", "situated", "one", "ones", "object",
    "objects",
];

const DETERMINERS: &[&str] = &["the", "a", "an", "this", "that", "these", "those", "some"];

fn number_word(word: &str) -> Option<usize> {
    const WORDS: &[&str] = &[
        "zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten",
    ];
    WORDS
        .iter()
        .position(|w| *w == word)
        .or_else(|| word.parse().ok())
        .filter(|n| *n >= 2)
}

fn superlative_word(word: &str) -> Option<Superlative> {
    Some(match word {
        "biggest" | "largest" | "big" | "large" | "bigger" | "larger" => Superlative::Biggest,
        "smallest" | "small" | "little" | "smaller" | "tiniest" | "tiny" => Superlative::Smallest,
        "tallest" | "tall" | "taller" => Superlative::Tallest,
        "highest" | "high" | "higher" | "topmost" | "uppermost" => Superlative::Highest,
        "lowest" | "low" | "lower" | "bottommost" => Superlative::Lowest,
        "leftmost" => Superlative::Leftmost,
        "rightmost" => Superlative::Rightmost,
        _ => return None,
    })
}

fn tokens(text: &str) -> Vec<String> {
    text.to_lowercase()
        .split(|c: char| !(c.is_alphanumeric() || c == '-' || c == '\''))
        .filter(|t| !t.is_empty())
        .map(|t| t.trim_matches('\'').to_owned())
        .filter(|t| !t.is_empty())
        .collect()
}

/// Parse `text` (see the module docs).
pub fn parse(text: &str) -> Result<Query, ParseError> {
    if text.len() > MAX_EXPRESSION_CHARS {
        return Err(ParseError::TooLong(text.len()));
    }
    let words = tokens(text);
    if words.is_empty() {
        return Err(ParseError::Empty);
    }
    let mut query = Query {
        text: text.trim().to_owned(),
        target: String::new(),
        function: false,
        count: Count::One,
        color: None,
        superlative: None,
        relation: None,
        anchors: Vec::new(),
        anchor_query: None,
    };
    if let Some(function) = function_phrase(&words) {
        query.function = true;
        query.count = function.0;
        query.target = function.1;
        return Ok(query);
    }
    // "the chair on the left" / "... on the right": view-dependent superlatives.
    let mut words = words;
    if words.len() >= 3 && words[words.len() - 3..] == ["on", "the", "left"] {
        words.truncate(words.len() - 3);
        query.superlative = Some(Superlative::Leftmost);
    } else if words.len() >= 3 && words[words.len() - 3..] == ["on", "the", "right"] {
        words.truncate(words.len() - 3);
        query.superlative = Some(Superlative::Rightmost);
    }
    let (head, relation, tail) = split_relation(&words);
    let head = describe_target(head, &mut query);
    if head.is_empty() {
        return Err(ParseError::NoTarget(query.text));
    }
    query.target = head.join(" ");
    if let Some(relation) = relation {
        query.relation = Some(relation);
        query.anchors = anchors(tail, relation);
        if let Some(anchor) = anchor_expression(tail, relation) {
            query.anchors = vec![anchor.target.clone()];
            query.anchor_query = Some(Box::new(anchor));
        }
        if query.anchors.len() < relation.anchors_needed() {
            return Err(ParseError::MissingAnchor {
                relation,
                needed: relation.anchors_needed(),
                text: query.text,
            });
        }
    }
    Ok(query)
}

/// "the thing you can X", "all the things you can X", "where one can X", "something to X",
/// "a place to X": (count, X).
fn function_phrase(words: &[String]) -> Option<(Count, String)> {
    let w: Vec<&str> = words.iter().map(String::as_str).collect();
    let mut i = 0;
    let mut count = Count::One;
    if w.first() == Some(&"all") {
        count = Count::All;
        i += 1;
    }
    while i < w.len() && DETERMINERS.contains(&w[i]) {
        i += 1;
    }
    let rest = &w[i..];
    let lead: &[&[&str]] = &[
        &["things", "you", "can"],
        &["things", "one", "can"],
        &["thing", "you", "can"],
        &["thing", "one", "can"],
        &["object", "you", "can"],
        &["where", "you", "can"],
        &["where", "one", "can"],
        &["where", "i", "can"],
        &["somewhere", "to"],
        &["something", "to"],
        &["things", "to"],
        &["thing", "to"],
        &["place", "to"],
        &["places", "to"],
    ];
    for phrase in lead {
        if rest.len() > phrase.len() && rest[..phrase.len()] == **phrase {
            if phrase[0].ends_with('s') && phrase[0] != "somewhere" {
                count = Count::All;
            }
            return Some((count, rest[phrase.len()..].join(" ")));
        }
    }
    None
}

/// The first relation phrase: words before it, the relation, words after it.
fn split_relation(words: &[String]) -> (&[String], Option<Relation>, &[String]) {
    // "with a lamp on it": the target supports the anchor.
    if let Some(with) = words.iter().position(|w| w == "with") {
        let after = &words[with + 1..];
        let ends_on_it = after.len() >= 3
            && after[after.len() - 2] == "on"
            && matches!(after[after.len() - 1].as_str(), "it" | "them" | "top");
        if ends_on_it {
            return (
                &words[..with],
                Some(Relation::Supporting),
                &after[..after.len() - 2],
            );
        }
    }
    // Skip the first word: "the", and a leading superlative like "closest" needs its noun first.
    for start in 1..words.len() {
        for (phrase, relation) in RELATION_PHRASES {
            let end = start + phrase.len();
            if end <= words.len()
                && words[start..end]
                    .iter()
                    .zip(phrase.iter())
                    .all(|(a, b)| a == b)
            {
                // "the chair closest" with nothing after: not a relation.
                if end < words.len() {
                    return (&words[..start], Some(*relation), &words[end..]);
                }
            }
        }
    }
    (words, None, &[])
}

/// Strip cardinality, determiners, colour and superlative words off the target phrase, noting
/// them in `query`; what is left is the concept.
fn describe_target<'a>(head: &'a [String], query: &mut Query) -> Vec<&'a str> {
    let mut out = Vec::new();
    let mut plural_determiner = false;
    for (i, word) in head.iter().enumerate() {
        let w = word.as_str();
        match w {
            "all" | "every" | "each" => query.count = Count::All,
            "both" => query.count = Count::Exactly(2),
            "these" | "those" => plural_determiner = true,
            _ if DETERMINERS.contains(&w) || FILLER.contains(&w) => {}
            "of" if out.is_empty() => {}
            _ if i + 1 < head.len() && number_word(w).is_some() && out.is_empty() => {
                query.count = Count::Exactly(number_word(w).unwrap_or(1));
            }
            _ if COLOR_WORDS.contains(&w) && i + 1 < head.len() => {
                query.color = Some(if w == "gray" { "grey".into() } else { w.into() });
            }
            _ if superlative_word(w).is_some() && i + 1 < head.len() && out.is_empty() => {
                query.superlative = superlative_word(w);
            }
            _ => out.push(w),
        }
    }
    // "the chairs" with no count word: every chair.
    let plural = out.last().is_some_and(|w| looks_plural(w));
    if query.count == Count::One && (plural || plural_determiner) {
        query.count = Count::All;
    }
    out
}

fn looks_plural(word: &str) -> bool {
    word.len() > 3
        && word.ends_with('s')
        && !word.ends_with("ss")
        && !word.ends_with("us")
        && !word.ends_with("is")
}

/// The anchor phrase after a relation as a referring expression of its own, when it is one (it
/// relates its object to another: "the chair farthest from the bed"); parsed by the same rules.
/// "Between" takes two plain anchors.
fn anchor_expression(tail: &[String], relation: Relation) -> Option<Query> {
    if relation == Relation::Between || split_relation(tail).1.is_none() {
        return None;
    }
    let anchor = parse(&tail.join(" ")).ok()?;
    (anchor.relation.is_some() && !anchor.function).then_some(anchor)
}

/// Anchor concepts after the relation phrase.
fn anchors(tail: &[String], relation: Relation) -> Vec<String> {
    let strip = |words: &[String]| -> String {
        words
            .iter()
            .map(String::as_str)
            .filter(|w| !DETERMINERS.contains(w) && !FILLER.contains(w))
            .collect::<Vec<_>>()
            .join(" ")
    };
    if relation == Relation::Between {
        if let Some(and) = tail.iter().position(|w| w == "and") {
            return [strip(&tail[..and]), strip(&tail[and + 1..])]
                .into_iter()
                .filter(|s| !s.is_empty())
                .collect();
        }
        // "between the two chairs": two instances of one concept.
        let words: Vec<String> = tail
            .iter()
            .filter(|w| number_word(w) != Some(2) && w.as_str() != "both")
            .cloned()
            .collect();
        let one = strip(&words);
        return if one.is_empty() {
            Vec::new()
        } else {
            vec![one.clone(), one]
        };
    }
    let anchor = strip(tail);
    if anchor.is_empty() {
        Vec::new()
    } else {
        vec![anchor]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_anchor_that_is_itself_a_referring_expression_is_parsed_as_one() {
        let q = p("the cabinet closest to the chair farthest from the bed");
        assert_eq!(
            (q.target.as_str(), q.relation),
            ("cabinet", Some(Relation::Closest))
        );
        assert_eq!(q.anchors, ["chair"]);
        let anchor = q.anchor_query.expect("a two-hop anchor");
        assert_eq!(anchor.target, "chair");
        assert_eq!(anchor.relation, Some(Relation::Farthest));
        assert_eq!(anchor.anchors, ["bed"]);
        assert!(anchor.anchor_query.is_none());
        // Plain anchors stay plain, and "between" takes two of them.
        assert!(p("the box on the table").anchor_query.is_none());
        let between = p("the box between the chair and the table next to the bed");
        assert!(between.anchor_query.is_none());
        assert_eq!(between.anchors.len(), 2);
    }

    fn p(text: &str) -> Query {
        parse(text).unwrap_or_else(|e| panic!("{text:?}: {e}"))
    }

    #[test]
    fn every_relation_phrase_parses_to_its_relation_and_anchor() {
        let table: &[(&str, Relation, &str, &str)] = &[
            (
                "the chair closest to the lamp",
                Relation::Closest,
                "chair",
                "lamp",
            ),
            (
                "the chair nearest to the lamp",
                Relation::Closest,
                "chair",
                "lamp",
            ),
            (
                "the chair next to the lamp",
                Relation::Closest,
                "chair",
                "lamp",
            ),
            (
                "the trash bin near the cabinet",
                Relation::Closest,
                "trash bin",
                "cabinet",
            ),
            (
                "the chair beside the lamp",
                Relation::Closest,
                "chair",
                "lamp",
            ),
            (
                "the chair farthest from the lamp",
                Relation::Farthest,
                "chair",
                "lamp",
            ),
            (
                "the chair furthest from the lamp",
                Relation::Farthest,
                "chair",
                "lamp",
            ),
            ("the lamp on the table", Relation::On, "lamp", "table"),
            ("the lamp on top of the desk", Relation::On, "lamp", "desk"),
            (
                "the box supported by the shelf",
                Relation::On,
                "box",
                "shelf",
            ),
            (
                "the table with a lamp on it",
                Relation::Supporting,
                "table",
                "lamp",
            ),
            (
                "the desk supporting the monitor",
                Relation::Supporting,
                "desk",
                "monitor",
            ),
            ("the lamp above the table", Relation::Above, "lamp", "table"),
            ("the box under the table", Relation::Below, "box", "table"),
            ("the box below the table", Relation::Below, "box", "table"),
            (
                "the chair to the left of the desk",
                Relation::Left,
                "chair",
                "desk",
            ),
            (
                "the chair left of the desk",
                Relation::Left,
                "chair",
                "desk",
            ),
            (
                "the chair to the right of the desk",
                Relation::Right,
                "chair",
                "desk",
            ),
            (
                "the chair in front of the desk",
                Relation::Front,
                "chair",
                "desk",
            ),
            (
                "the chair behind the desk",
                Relation::Behind,
                "chair",
                "desk",
            ),
            (
                "the chair that is next to the bed",
                Relation::Closest,
                "chair",
                "bed",
            ),
        ];
        for (text, relation, target, anchor) in table {
            let q = p(text);
            assert_eq!(q.relation, Some(*relation), "{text}");
            assert_eq!(q.target, *target, "{text}");
            assert_eq!(q.anchors, [anchor.to_string()], "{text}");
            assert_eq!(q.count, Count::One, "{text}");
        }
        assert!(p("the chair to the left of the desk").view_dependent());
        assert!(!p("the lamp on the table").view_dependent());
    }

    #[test]
    fn between_takes_two_anchors_or_one_concept_twice() {
        let q = p("the table between the sofa and the bed");
        assert_eq!(q.relation, Some(Relation::Between));
        assert_eq!(q.anchors, ["sofa", "bed"]);
        let q = p("the lamp between the two chairs");
        assert_eq!(q.anchors, ["chairs", "chairs"]);
        assert!(matches!(
            parse("the lamp between the"),
            Err(ParseError::MissingAnchor { .. })
        ));
    }

    #[test]
    fn superlatives_and_size_words_are_attributes_of_the_target() {
        let table: &[(&str, Superlative)] = &[
            ("the biggest chair", Superlative::Biggest),
            ("the largest box", Superlative::Biggest),
            ("the smallest box", Superlative::Smallest),
            ("the small box", Superlative::Smallest),
            ("the tallest cabinet", Superlative::Tallest),
            ("the highest box", Superlative::Highest),
            ("the lowest box", Superlative::Lowest),
            ("the leftmost chair", Superlative::Leftmost),
            ("the rightmost chair", Superlative::Rightmost),
            ("the chair on the left", Superlative::Leftmost),
            ("the chair on the right", Superlative::Rightmost),
        ];
        for (text, superlative) in table {
            let q = p(text);
            assert_eq!(q.superlative, Some(*superlative), "{text}");
            assert!(q.target == "chair" || q.target == "box" || q.target == "cabinet");
            assert_eq!(q.relation, None, "{text}");
        }
        assert!(p("the leftmost chair").view_dependent());
    }

    #[test]
    fn cardinality_words_set_the_count() {
        assert_eq!(p("the chair").count, Count::One);
        assert_eq!(p("a chair").count, Count::One);
        assert_eq!(p("both chairs").count, Count::Exactly(2));
        assert_eq!(p("the two boxes").count, Count::Exactly(2));
        assert_eq!(p("3 pillows").count, Count::Exactly(3));
        assert_eq!(p("all the chairs").count, Count::All);
        assert_eq!(p("the chairs").count, Count::All);
        assert_eq!(p("every lamp").count, Count::All);
        // Singular nouns ending in s are not plurals.
        assert_eq!(p("the glass").count, Count::One);
        assert_eq!(p("both chairs").target, "chairs");
    }

    #[test]
    fn colour_words_are_attributes() {
        let q = p("the red chair");
        assert_eq!(q.color.as_deref(), Some("red"));
        assert_eq!(q.target, "chair");
        assert_eq!(p("the gray box").color.as_deref(), Some("grey"));
        // A colour alone is the concept, not an attribute of nothing.
        assert_eq!(p("the red").target, "red");
    }

    #[test]
    fn function_phrases_name_what_one_does_with_the_target() {
        let q = p("the thing you can wash hands");
        assert!(q.function);
        assert_eq!(q.target, "wash hands");
        assert_eq!(q.count, Count::One);
        let q = p("all the things you can sit on");
        assert_eq!((q.target.as_str(), q.count), ("sit on", Count::All));
        assert_eq!(p("where one can wash hands").target, "wash hands");
        assert_eq!(p("a place to sleep").target, "sleep");
        assert_eq!(p("something to sit on").target, "sit on");
    }

    #[test]
    fn open_vocabulary_phrases_pass_through_as_concepts() {
        assert_eq!(p("the garbage can").target, "garbage can");
        assert_eq!(p("The Computer Screen!").target, "computer screen");
        assert_eq!(p("couch").target, "couch");
    }

    #[test]
    fn garbage_empty_and_huge_inputs_are_clear_errors() {
        assert_eq!(parse(""), Err(ParseError::Empty));
        assert_eq!(parse("   ?!  "), Err(ParseError::Empty));
        assert!(matches!(parse("the the the"), Err(ParseError::NoTarget(_))));
        let huge = "chair ".repeat(2000);
        assert_eq!(parse(&huge), Err(ParseError::TooLong(huge.len())));
        assert!(matches!(
            parse("the chair next to"),
            Ok(Query { relation: None, .. })
        ));
        // Non-ASCII is fine: a phrase for the encoder.
        assert_eq!(p("la chaise près de la lampe").relation, None);
    }
}
