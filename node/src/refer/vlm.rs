//! The VLM reasoner: the evidence bundle sent to a vision-language model through the OpenAI chat
//! completions API as vLLM (or any compatible server) serves it: the structured candidates as
//! text, the images as data-URL `image_url` parts, the answer constrained to a JSON schema whose
//! ids are the candidates' (`response_format`). The answer is validated (JSON, ids in the
//! candidate set, no repeats, the count the expression asks for); anything else is an error the
//! caller turns into the built-in reasoner's answer, saying why.

use std::time::Duration;

use base64::Engine;
use serde::{Deserialize, Serialize};
use serde_json::json;

use super::evidence::{png, Evidence};
use super::parse::{Count, Query, Relation, Superlative, COLOR_WORDS};

/// The largest VLM response body read (bytes).
pub const MAX_ANSWER_BYTES: u64 = 1 << 20;

/// The `refer.vlm` section of the node's config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VlmSection {
    /// Base URL of the OpenAI-compatible API, e.g. `http://localhost:8000/v1` ("" = no VLM).
    pub endpoint: String,
    /// Model name the server serves.
    pub model: String,
    pub timeout_secs: f64,
    /// Images per request (the overview first, then candidates).
    pub max_images: usize,
    /// Environment variable holding the API key (sent as a bearer token when set).
    pub api_key_env: String,
}

impl Default for VlmSection {
    fn default() -> Self {
        Self {
            endpoint: String::new(),
            model: String::new(),
            timeout_secs: 10.0,
            max_images: 4,
            api_key_env: "OPENAI_API_KEY".into(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VlmError {
    #[error("no VLM endpoint is configured (refer.vlm.endpoint)")]
    NotConfigured,
    #[error("VLM request failed: {0}")]
    Transport(String),
    #[error("VLM did not answer within {0:?}")]
    Timeout(Duration),
    #[error("VLM answered HTTP {status}: {body}")]
    Http { status: u16, body: String },
    #[error("VLM answer is not the expected JSON: {0}")]
    NotJson(String),
    #[error("VLM chose {0:?}, which is not a candidate")]
    NotACandidate(String),
    #[error("VLM chose {got} instance(s); the expression asks for {wanted}")]
    WrongCount { got: usize, wanted: String },
}

/// What the VLM chose, and its reason.
#[derive(Debug, Clone, PartialEq)]
pub struct VlmChoice {
    pub ids: Vec<String>,
    pub reason: String,
}

/// A client of one configured server.
#[derive(Debug, Clone)]
pub struct VlmClient {
    section: VlmSection,
    agent: ureq::Agent,
}

impl VlmClient {
    pub fn new(section: &VlmSection) -> Result<Self, VlmError> {
        if section.endpoint.is_empty() {
            return Err(VlmError::NotConfigured);
        }
        let timeout = Duration::from_secs_f64(section.timeout_secs.max(0.001));
        let agent = ureq::Agent::config_builder()
            .timeout_global(Some(timeout))
            .http_status_as_error(false)
            .build()
            .into();
        Ok(Self {
            section: section.clone(),
            agent,
        })
    }

    /// The chat completions request body for `evidence`.
    pub fn request_body(
        &self,
        expression: &str,
        count: Count,
        evidence: &Evidence,
        candidate_ids: &[String],
    ) -> serde_json::Value {
        let wanted = match count {
            Count::One => "exactly one".to_owned(),
            Count::Exactly(n) => format!("exactly {n}"),
            Count::All => "every candidate that fits (at least one)".to_owned(),
        };
        let text = format!(
            "A robot's 3D map holds the numbered candidate objects below (JSON). The images are \
             the robot's camera pictures (or renders of its map where it kept none): the first is \
             an overview with each candidate's outline and number, the others highlight one \
             candidate each. Which candidate(s) does the \
             expression {expression:?} mean? Choose {wanted}, only among the candidates' ids, and \
             answer JSON {{\"ids\": [...], \"reason\": \"...\"}}.\n{}",
            evidence.json
        );
        let mut content = vec![json!({"type": "text", "text": text})];
        for (_, image) in evidence.images.iter().take(self.section.max_images) {
            if let Ok(bytes) = png(image) {
                let url = format!(
                    "data:image/png;base64,{}",
                    base64::engine::general_purpose::STANDARD.encode(bytes)
                );
                content.push(json!({"type": "image_url", "image_url": {"url": url}}));
            }
        }
        let schema = json!({
            "type": "object",
            "properties": {
                "ids": {"type": "array", "items": {"type": "string", "enum": candidate_ids}},
                "reason": {"type": "string"},
            },
            "required": ["ids"],
        });
        self.chat_body(
            "You resolve referring expressions to objects in a 3D map. Answer only with JSON.",
            json!(content),
            "referring_answer",
            schema,
        )
    }

    /// A chat completions body: a system prompt, one user message, a JSON-schema answer.
    fn chat_body(
        &self,
        system: &str,
        user: serde_json::Value,
        name: &str,
        schema: serde_json::Value,
    ) -> serde_json::Value {
        json!({
            "model": self.section.model,
            "messages": [
                {"role": "system", "content": system},
                {"role": "user", "content": user},
            ],
            "temperature": 0,
            "max_tokens": 256,
            "response_format": {"type": "json_schema", "json_schema": {"name": name, "schema": schema}},
        })
    }

    /// POST a chat completions `body`; the response body of a 200 answer.
    fn complete(&self, body: &serde_json::Value) -> Result<String, VlmError> {
        let url = format!(
            "{}/chat/completions",
            self.section.endpoint.trim_end_matches('/')
        );
        let mut request = self
            .agent
            .post(&url)
            .header("Content-Type", "application/json");
        if let Some(key) = std::env::var(&self.section.api_key_env)
            .ok()
            .filter(|k| !k.is_empty())
        {
            request = request.header("Authorization", &format!("Bearer {key}"));
        }
        let timeout = Duration::from_secs_f64(self.section.timeout_secs.max(0.001));
        let transport = |e: ureq::Error| match e {
            ureq::Error::Timeout(_) => VlmError::Timeout(timeout),
            other => VlmError::Transport(other.to_string()),
        };
        let mut response = request.send(body.to_string()).map_err(transport)?;
        let status = response.status().as_u16();
        // An answer is a few hundred bytes of JSON (max_tokens 256); a server that sends more is
        // refused before it can fill memory.
        let text = response
            .body_mut()
            .with_config()
            .limit(MAX_ANSWER_BYTES)
            .read_to_string()
            .map_err(transport)?;
        if status != 200 {
            return Err(VlmError::Http {
                status,
                body: text.chars().take(200).collect(),
            });
        }
        Ok(text)
    }

    /// Decompose `expression` with the LLM into the parser's schema, validated; an error says why
    /// (the caller then uses the rule parser).
    pub fn parse(&self, expression: &str) -> Result<Query, VlmError> {
        let options = |names: Vec<String>| -> Vec<serde_json::Value> {
            names
                .into_iter()
                .map(|n| json!(n))
                .chain([serde_json::Value::Null])
                .collect()
        };
        let schema = json!({
            "type": "object",
            "properties": {
                "target": {"type": "string"},
                "function": {"type": "boolean"},
                "count": {"type": "string", "enum": ["one", "all", "exactly"]},
                "n": {"type": "integer", "minimum": 2},
                "color": {"enum": options(COLOR_WORDS.iter().map(|c| (*c).to_owned()).collect())},
                "superlative": {"enum": options(ALL_SUPERLATIVES.iter().map(snake).collect())},
                "relation": {"enum": options(ALL_RELATIONS.iter().map(snake).collect())},
                "anchors": {"type": "array", "items": {"type": "string"}},
            },
            "required": ["target", "count", "anchors"],
        });
        let body = self.chat_body(
            "Decompose a referring expression about objects in a room into JSON: the target (a \
             noun phrase, or for a function what one does with it), how many are meant, colour, \
             superlative, at most one spatial relation and its anchor objects (two for between). \
             Answer only with JSON.",
            json!(expression),
            "referring_parse",
            schema,
        );
        let text = self.complete(&body)?;
        parse_decomposition(&text, expression)
    }

    /// Ask the VLM; a validated choice or why not.
    pub fn choose(
        &self,
        expression: &str,
        count: Count,
        evidence: &Evidence,
        candidate_ids: &[String],
    ) -> Result<VlmChoice, VlmError> {
        let body = self.request_body(expression, count, evidence, candidate_ids);
        let text = self.complete(&body)?;
        parse_choice(&text, count, candidate_ids)
    }
}

const ALL_RELATIONS: [Relation; 11] = [
    Relation::Closest,
    Relation::Farthest,
    Relation::Above,
    Relation::Below,
    Relation::On,
    Relation::Supporting,
    Relation::Left,
    Relation::Right,
    Relation::Front,
    Relation::Behind,
    Relation::Between,
];

const ALL_SUPERLATIVES: [Superlative; 7] = [
    Superlative::Biggest,
    Superlative::Smallest,
    Superlative::Tallest,
    Superlative::Highest,
    Superlative::Lowest,
    Superlative::Leftmost,
    Superlative::Rightmost,
];

/// The snake_case name serde gives an enum value.
fn snake<T: Serialize>(value: &T) -> String {
    serde_json::to_value(value)
        .ok()
        .and_then(|v| v.as_str().map(str::to_owned))
        .unwrap_or_default()
}

/// The JSON object in a chat completions body's first message (markdown fences tolerated).
fn message_json(body: &str) -> Result<serde_json::Value, VlmError> {
    let reply: serde_json::Value =
        serde_json::from_str(body).map_err(|e| VlmError::NotJson(format!("response body: {e}")))?;
    let content = reply["choices"][0]["message"]["content"]
        .as_str()
        .ok_or_else(|| VlmError::NotJson("no choices[0].message.content".into()))?;
    // Models sometimes fence JSON in markdown even when asked not to.
    let content = content
        .trim()
        .trim_start_matches("```json")
        .trim_start_matches("```")
        .trim_end_matches("```")
        .trim();
    serde_json::from_str(content).map_err(|e| VlmError::NotJson(format!("message content: {e}")))
}

/// Validate an LLM decomposition against the parser's schema.
pub fn parse_decomposition(body: &str, expression: &str) -> Result<Query, VlmError> {
    let v = message_json(body)?;
    let invalid = |what: String| VlmError::NotJson(format!("decomposition: {what}"));
    let target = v["target"]
        .as_str()
        .map(str::trim)
        .filter(|t| !t.is_empty() && t.len() <= super::parse::MAX_EXPRESSION_CHARS)
        .ok_or_else(|| invalid("no target".into()))?
        .to_lowercase();
    let count = match v["count"].as_str() {
        Some("one") => Count::One,
        Some("all") => Count::All,
        Some("exactly") => Count::Exactly(
            v["n"]
                .as_u64()
                .filter(|n| (2..=1000).contains(n))
                .ok_or_else(|| invalid("`exactly` needs n >= 2".into()))? as usize,
        ),
        other => return Err(invalid(format!("count {other:?}"))),
    };
    let named = |field: &str, names: &[String]| -> Result<Option<usize>, VlmError> {
        match &v[field] {
            serde_json::Value::Null => Ok(None),
            serde_json::Value::String(s) => names
                .iter()
                .position(|n| n == s)
                .map(Some)
                .ok_or_else(|| invalid(format!("{field} {s:?}"))),
            other => Err(invalid(format!("{field} {other}"))),
        }
    };
    let relations: Vec<String> = ALL_RELATIONS.iter().map(snake).collect();
    let superlatives: Vec<String> = ALL_SUPERLATIVES.iter().map(snake).collect();
    let colors: Vec<String> = COLOR_WORDS.iter().map(|c| (*c).to_owned()).collect();
    let relation = named("relation", &relations)?.map(|i| ALL_RELATIONS[i]);
    let superlative = named("superlative", &superlatives)?.map(|i| ALL_SUPERLATIVES[i]);
    let color = named("color", &colors)?.map(|i| colors[i].clone());
    let anchors: Vec<String> = v["anchors"]
        .as_array()
        .ok_or_else(|| invalid("no anchors array".into()))?
        .iter()
        .map(|a| {
            a.as_str()
                .map(|s| s.trim().to_lowercase())
                .filter(|s| !s.is_empty())
        })
        .collect::<Option<_>>()
        .ok_or_else(|| invalid("an anchor is not a phrase".into()))?;
    let needed = relation.map_or(0, Relation::anchors_needed);
    if anchors.len() != needed {
        return Err(invalid(format!(
            "{} anchor(s) for relation {relation:?}",
            anchors.len()
        )));
    }
    Ok(Query {
        text: expression.trim().to_owned(),
        target,
        function: v["function"].as_bool().unwrap_or(false),
        count,
        color,
        superlative,
        relation,
        anchors,
        anchor_query: None,
    })
}

/// Validate a chat completions response body.
pub fn parse_choice(
    body: &str,
    count: Count,
    candidate_ids: &[String],
) -> Result<VlmChoice, VlmError> {
    let answer = message_json(body)?;
    let ids: Vec<String> = answer["ids"]
        .as_array()
        .ok_or_else(|| VlmError::NotJson("no `ids` array".into()))?
        .iter()
        .map(|v| {
            v.as_str()
                .map(str::to_owned)
                .ok_or_else(|| VlmError::NotJson(format!("id {v} is not a string")))
        })
        .collect::<Result<_, _>>()?;
    for id in &ids {
        if !candidate_ids.contains(id) {
            return Err(VlmError::NotACandidate(id.clone()));
        }
    }
    let mut unique = ids.clone();
    unique.sort();
    unique.dedup();
    let count_ok = match count {
        Count::One => unique.len() == 1,
        Count::Exactly(n) => unique.len() == n.min(candidate_ids.len()),
        Count::All => !unique.is_empty(),
    };
    if unique.len() != ids.len() || !count_ok {
        return Err(VlmError::WrongCount {
            got: ids.len(),
            wanted: format!("{count:?}"),
        });
    }
    Ok(VlmChoice {
        ids,
        reason: answer["reason"].as_str().unwrap_or("").to_owned(),
    })
}
