#![allow(clippy::unwrap_used)]
//! The VLM reasoner's client against a scripted test server speaking the OpenAI chat completions
//! protocol: a valid answer is taken; every fault (timeout, HTTP 500, non-JSON, ids outside the
//! candidate set, the wrong count, no server, none configured) leaves the built-in reasoner's
//! answer standing, marked `fallback` with the reason.

use std::time::Duration;

use glam::DVec3;
use groupforward::frame::RgbImage;
use groupforward::recon::boxes::OrientedBox;
use groupforward::refer::evidence::Evidence;
use groupforward::refer::scripted_chat::{
    vlm_faults, ScriptedChatServer, ScriptedReply, VlmFault, FAULT_TIMEOUT_SECS,
};
use groupforward::refer::vlm::{VlmClient, VlmError, VlmSection};
use groupforward::refer::{
    answer, with_vlm, Answer, Count, Embed, Query, ReferNode, ReferScene, ReferSection, Relation,
    Request,
};

struct OneHot;

impl Embed for OneHot {
    fn embed(&mut self, phrase: &str) -> Result<Vec<f32>, String> {
        Ok(match phrase {
            "chair" | "chairs" => vec![1.0, 0.0],
            "lamp" => vec![0.0, 1.0],
            other => return Err(format!("no embedding for {other:?}")),
        })
    }
}

fn node(id: &str, class: usize, x: f64) -> ReferNode {
    let (lo, hi) = (DVec3::new(x, 0.0, 0.0), DVec3::new(x + 0.5, 0.5, 0.9));
    let mut names = vec![0.05, 0.05];
    names[class] = 0.95;
    ReferNode {
        id: id.into(),
        names,
        label: ["chair", "lamp"][class].into(),
        bbox: OrientedBox::from_bounds(lo, hi),
        lo,
        hi,
        color: [0.5; 3],
        visibility: 1.0,
        confidence: 1.0,
        gaussians: 10,
        tentative: false,
    }
}

/// Two chairs and a lamp; the built-in reasoner picks inst_000001 (next to the lamp).
fn scene() -> ReferScene {
    ReferScene {
        nodes: vec![
            node("inst_000001", 0, 1.0),
            node("inst_000002", 0, 4.0),
            node("inst_000003", 1, 0.0),
        ],
        phrases: vec!["chair".into(), "lamp".into()],
        embeddings: vec![vec![1.0, 0.0], vec![0.0, 1.0]],
        ..ReferScene::default()
    }
}

fn builtin(expression: &str) -> Answer {
    answer(
        &scene(),
        &mut OneHot,
        &Request {
            expression: expression.into(),
            ..Request::default()
        },
        &ReferSection::default(),
    )
    .unwrap()
}

fn evidence() -> Evidence {
    Evidence {
        json: serde_json::json!({"candidates": []}),
        images: vec![(
            "overview".into(),
            RgbImage {
                width: 4,
                height: 3,
                data: vec![128; 36],
            },
        )],
    }
}

fn ask(expression: &str, reply: ScriptedReply, timeout_secs: f64) -> (Answer, ScriptedChatServer) {
    let server = ScriptedChatServer::start(vec![reply]).unwrap();
    let section = VlmSection {
        endpoint: server.url.clone(),
        model: "scripted".into(),
        timeout_secs,
        ..VlmSection::default()
    };
    let client = VlmClient::new(&section).unwrap();
    (
        with_vlm(builtin(expression), Ok(&client), &evidence()),
        server,
    )
}

fn chosen(a: &Answer) -> Vec<String> {
    let scene = scene();
    a.chosen
        .iter()
        .map(|c| scene.nodes[c.index].id.clone())
        .collect()
}

#[test]
fn a_valid_answer_is_taken_and_the_request_speaks_the_openai_protocol() {
    let before = builtin("the chair closest to the lamp");
    assert_eq!(chosen(&before), ["inst_000001"]);
    let (a, server) = ask(
        "the chair closest to the lamp",
        ScriptedReply::content(r#"{"ids": ["inst_000002"], "reason": "scripted"}"#),
        5.0,
    );
    assert_eq!(a.reasoner_used, "vlm");
    assert_eq!(chosen(&a), ["inst_000002"]);
    assert!(a.trace.contains("scripted"), "{}", a.trace);
    let requests = server.requests.lock().unwrap();
    let (line, body) = &requests[0];
    assert!(line.starts_with("POST /v1/chat/completions"), "{line}");
    let body: serde_json::Value = serde_json::from_str(body).unwrap();
    assert_eq!(body["model"], "scripted");
    let content = body["messages"][1]["content"].as_array().unwrap();
    assert_eq!(content[0]["type"], "text");
    assert!(content[1]["image_url"]["url"]
        .as_str()
        .unwrap()
        .starts_with("data:image/png;base64,"));
    let ids =
        &body["response_format"]["json_schema"]["schema"]["properties"]["ids"]["items"]["enum"];
    assert_eq!(ids.as_array().unwrap().len(), a.candidates.len());
}

#[test]
fn markdown_fenced_json_is_accepted() {
    let (a, _server) = ask(
        "the chair closest to the lamp",
        ScriptedReply::content("```json\n{\"ids\": [\"inst_000001\"]}\n```"),
        5.0,
    );
    assert_eq!(a.reasoner_used, "vlm");
}

#[test]
fn every_vlm_fault_falls_back_to_the_builtin_answer_and_says_why() {
    let faults = vlm_faults("inst_000002", ["inst_000001", "inst_000002"]);
    assert_eq!(FAULT_TIMEOUT_SECS, 0.5);
    for VlmFault {
        name,
        reply,
        reason,
    } in faults
    {
        let (a, _server) = ask("the chair closest to the lamp", reply, FAULT_TIMEOUT_SECS);
        assert_eq!(a.reasoner_used, "fallback", "{name}");
        assert!(a.trace.contains(reason), "{name}: {}", a.trace);
        assert_eq!(
            chosen(&a),
            ["inst_000001"],
            "{name}: the built-in answer stands"
        );
    }
}

#[test]
fn no_server_and_no_configuration_fall_back_too() {
    // A port nothing listens on.
    let closed = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}/v1", closed.local_addr().unwrap());
    drop(closed);
    let client = VlmClient::new(&VlmSection {
        endpoint: url,
        timeout_secs: 1.0,
        ..VlmSection::default()
    })
    .unwrap();
    let a = with_vlm(
        builtin("the chair closest to the lamp"),
        Ok(&client),
        &evidence(),
    );
    assert_eq!(a.reasoner_used, "fallback");
    assert!(a.trace.contains("request failed"), "{}", a.trace);
    let unconfigured = VlmClient::new(&VlmSection::default());
    let a = with_vlm(
        builtin("the chair closest to the lamp"),
        unconfigured.as_ref().map_err(Clone::clone),
        &evidence(),
    );
    assert_eq!(a.reasoner_used, "fallback");
    assert!(a.trace.contains("no VLM endpoint"), "{}", a.trace);
}

#[test]
fn cardinality_is_checked_for_plural_expressions() {
    let (a, _server) = ask(
        "both chairs",
        ScriptedReply::content(r#"{"ids": ["inst_000002"]}"#),
        5.0,
    );
    assert_eq!(a.reasoner_used, "fallback");
    let (a, _server) = ask(
        "both chairs",
        ScriptedReply::content(r#"{"ids": ["inst_000002", "inst_000001"]}"#),
        5.0,
    );
    assert_eq!(a.reasoner_used, "vlm");
    assert_eq!(a.chosen.len(), 2);
}

fn llm_parse(reply: ScriptedReply) -> (Result<Query, VlmError>, ScriptedChatServer) {
    let server = ScriptedChatServer::start(vec![reply]).unwrap();
    let client = VlmClient::new(&VlmSection {
        endpoint: server.url.clone(),
        timeout_secs: 2.0,
        ..VlmSection::default()
    })
    .unwrap();
    (client.parse("the seat nearest the bin"), server)
}

#[test]
fn an_llm_decomposition_is_validated_against_the_parser_s_schema() {
    let (query, server) = llm_parse(ScriptedReply::content(
        r#"{"target": "Chair", "function": false, "count": "one", "color": null, "superlative": null, "relation": "closest", "anchors": ["trash bin"]}"#,
    ));
    let query = query.unwrap();
    assert_eq!(query.target, "chair");
    assert_eq!(query.relation, Some(Relation::Closest));
    assert_eq!(query.anchors, ["trash bin"]);
    assert_eq!(query.count, Count::One);
    assert_eq!(query.text, "the seat nearest the bin");
    let body: serde_json::Value =
        serde_json::from_str(&server.requests.lock().unwrap()[0].1).unwrap();
    assert_eq!(body["messages"][1]["content"], "the seat nearest the bin");
    assert!(
        body["response_format"]["json_schema"]["schema"]["properties"]["relation"]["enum"]
            .as_array()
            .unwrap()
            .contains(&serde_json::json!("between"))
    );
    let (query, _server) = llm_parse(ScriptedReply::content(
        r#"{"target": "chairs", "count": "exactly", "n": 2, "anchors": []}"#,
    ));
    assert_eq!(query.unwrap().count, Count::Exactly(2));
}

#[test]
fn an_invalid_decomposition_is_an_error_the_rule_parser_then_answers() {
    let bad = [
        r#"{"target": "", "count": "one", "anchors": []}"#,
        r#"{"target": "chair", "count": "some", "anchors": []}"#,
        r#"{"target": "chair", "count": "exactly", "anchors": []}"#,
        r#"{"target": "chair", "count": "one", "relation": "inside", "anchors": ["box"]}"#,
        r#"{"target": "chair", "count": "one", "relation": "between", "anchors": ["lamp"]}"#,
        r#"{"target": "chair", "count": "one", "relation": null, "anchors": ["lamp"]}"#,
        r#"{"target": "chair", "count": "one", "color": "ultraviolet", "anchors": []}"#,
        "a chair, probably",
    ];
    for content in bad {
        let (query, _server) = llm_parse(ScriptedReply::content(content));
        assert!(
            matches!(query, Err(VlmError::NotJson(_))),
            "{content}: {query:?}"
        );
    }
    let (query, _server) = llm_parse(ScriptedReply {
        status: 503,
        body: "busy".into(),
        delay: Duration::ZERO,
        drip_bytes: None,
    });
    assert!(matches!(query, Err(VlmError::Http { status: 503, .. })));
}
