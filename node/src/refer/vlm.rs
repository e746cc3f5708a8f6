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
use super::parse::Count;

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
             rendered from the map: the first is an overview with each candidate's outline and \
             number, the others highlight one candidate each. Which candidate(s) does the \
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
        json!({
            "model": self.section.model,
            "messages": [
                {"role": "system", "content": "You resolve referring expressions to objects in a 3D map. Answer only with JSON."},
                {"role": "user", "content": content},
            ],
            "temperature": 0,
            "max_tokens": 256,
            "response_format": {"type": "json_schema", "json_schema": {"name": "referring_answer", "schema": schema}},
        })
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
        let mut response = request.send(body.to_string()).map_err(|e| match e {
            ureq::Error::Timeout(_) => VlmError::Timeout(timeout),
            other => VlmError::Transport(other.to_string()),
        })?;
        let status = response.status().as_u16();
        let text = response.body_mut().read_to_string().map_err(|e| match e {
            ureq::Error::Timeout(_) => VlmError::Timeout(timeout),
            other => VlmError::Transport(other.to_string()),
        })?;
        if status != 200 {
            return Err(VlmError::Http {
                status,
                body: text.chars().take(200).collect(),
            });
        }
        parse_choice(&text, count, candidate_ids)
    }
}

/// Validate a chat completions response body.
pub fn parse_choice(
    body: &str,
    count: Count,
    candidate_ids: &[String],
) -> Result<VlmChoice, VlmError> {
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
    let answer: serde_json::Value = serde_json::from_str(content)
        .map_err(|e| VlmError::NotJson(format!("message content: {e}")))?;
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
