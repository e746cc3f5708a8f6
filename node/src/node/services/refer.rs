//! The `Refer` service and the JSON API's `refer`: a request decoded, parsed against the current
//! snapshot of the map, answered by the configured reasoner on the query pool, and encoded.

use std::sync::Mutex;

use glam::{DQuat, DVec3};
use groupforward_msgs::cdr;
use groupforward_msgs::gf_msgs::{ReferRequest, ReferResponse};
use groupforward_relations::ViewPose;

use super::shared::{query_snapshot, Shared};
use crate::frame::Keyframe;
use crate::recon::Rigid;
use crate::refer::{self, ReferSection};
use crate::timing::Stage;

/// The view a request decides view-dependent words in: its pose when it gives one.
fn request_view(request: &ReferRequest) -> std::result::Result<Option<ViewPose>, String> {
    if !request.use_view_pose {
        return Ok(None);
    }
    let p = &request.view_pose;
    let rotation = DQuat::from_xyzw(
        p.orientation.x,
        p.orientation.y,
        p.orientation.z,
        p.orientation.w,
    );
    let position = DVec3::new(p.position.x, p.position.y, p.position.z);
    if !(position.is_finite() && rotation.is_finite()) || (rotation.length() - 1.0).abs() > 1e-3 {
        return Err("view_pose is not a finite pose with a unit quaternion".into());
    }
    Ok(Some(ViewPose::new(0, rotation.normalize(), position)))
}

/// The query to answer: the LLM's decomposition when `refer.llm_parse` is on and it validates,
/// else the rule parser's `rule`; with a note for the trace.
fn parse_query(
    expression: &str,
    rule: refer::Query,
    section: &ReferSection,
) -> (refer::Query, Option<String>) {
    if !section.llm_parse {
        return (rule, None);
    }
    match refer::vlm::VlmClient::new(&section.vlm).and_then(|client| client.parse(expression)) {
        Ok(query) => (query, Some("parsed by the LLM".into())),
        Err(e) => (rule, Some(format!("LLM parse failed ({e}): rule parser"))),
    }
}

/// Answer a referring request on the node's current snapshot (the service's work, CDR aside),
/// timed as the query stage.
pub fn refer_request(shared: &Mutex<Shared>, request: &ReferRequest) -> ReferResponse {
    let started = std::time::Instant::now();
    let response = answer_refer(shared, request);
    if let Ok(mut s) = shared.lock() {
        s.stages.record(Stage::Query, started.elapsed());
    }
    response
}

fn answer_refer(shared: &Mutex<Shared>, request: &ReferRequest) -> ReferResponse {
    let failure = |message: String| {
        // A question the map cannot answer is an answer, not a fault of the node.
        tracing::info!("refer {:?}: {message}", request.expression);
        ReferResponse {
            success: false,
            message,
            ..ReferResponse::default()
        }
    };
    // Bad input is refused first, whatever state the node is in.
    let rule = match refer::parse(&request.expression) {
        Ok(query) => query,
        Err(e) => return failure(refer::ReferError::from(e).to_string()),
    };
    let view = match request_view(request) {
        Ok(view) => view,
        Err(message) => return failure(message),
    };
    // Read what the query needs, then answer without holding the map's lock.
    let scene = match query_snapshot(shared) {
        Ok(scene) => scene,
        Err(e) => return failure(format!("no snapshot of the map: {e}")),
    };
    let (encoder, section, world_frame) = match shared.lock() {
        Ok(s) => (
            s.text_encoder.clone(),
            s.refer.clone(),
            s.world_frame.clone(),
        ),
        Err(e) => return failure(e.to_string()),
    };
    let Some(encoder) = encoder else {
        return failure("the text encoder is not loaded (yet): no phrase can be matched".into());
    };
    let reasoner = if request.reasoner.is_empty() {
        section.reasoner.as_str()
    } else {
        request.reasoner.as_str()
    };
    if !matches!(reasoner, "builtin" | "vlm") {
        return failure(format!(
            "unknown reasoner {reasoner:?}; use \"builtin\" or \"vlm\""
        ));
    }
    let answered = {
        let Ok(mut encoder) = encoder.lock() else {
            return failure("the text encoder's lock is poisoned".into());
        };
        let (query, parsed_by) = parse_query(&request.expression, rule, &section);
        refer::answer_query(
            &scene,
            &mut *encoder,
            query,
            &refer::Request {
                expression: request.expression.clone(),
                view,
                max_targets: request.max_targets as usize,
            },
            &section,
        )
        .map(|mut answer| {
            if let Some(note) = parsed_by {
                answer.trace = format!("{note}; {}", answer.trace);
            }
            answer
        })
    };
    let mut answer = match answered {
        Ok(answer) => answer,
        Err(e) => return failure(e.to_string()),
    };
    if reasoner == "vlm" || !section.evidence_dir.is_empty() {
        let all: Vec<(String, crate::recon::gaussians::Gaussians)> = scene
            .map
            .instances
            .iter()
            .map(|i| (i.id.clone(), i.gaussians.clone()))
            .collect();
        let images = if reasoner == "vlm" {
            section.vlm.max_images
        } else {
            1 + 3 * section.top_k
        };
        let evidence = refer::evidence::build(&scene, &answer, &all, images);
        if reasoner == "vlm" {
            let client = refer::vlm::VlmClient::new(&section.vlm);
            answer = refer::with_vlm(answer, client.as_ref().map_err(Clone::clone), &evidence);
        }
        if !section.evidence_dir.is_empty() {
            let stem = refer::evidence::stem(&request.expression);
            if let Err(e) = refer::evidence::write(
                std::path::Path::new(&section.evidence_dir),
                &stem,
                &evidence,
            ) {
                tracing::warn!("evidence not written to {}: {e}", section.evidence_dir);
            }
        }
    }
    // From the snapshot that chose them: consistent even if the live map moved on since.
    let gaussians: Vec<_> = answer
        .chosen
        .iter()
        .map(|c| scene.gaussians(&scene.nodes[c.index].id))
        .collect();
    let novel = view
        .zip(scene.keyframes.first())
        .map(|(v, latest)| Keyframe {
            stamp_nanos: latest.stamp_nanos,
            camera: latest.camera,
            world_from_camera: Rigid::new(
                DQuat::from_array(v.orientation),
                DVec3::from(v.position),
            ),
        });
    on_query_pool(|| {
        refer::response::response(&answer, &scene, &gaussians, &world_frame, novel.as_ref())
    })
}

/// Threads of the pool that renders answers' masks and clouds.
const QUERY_THREADS: usize = 2;

/// Run `work` on the queries' own rayon pool: in rayon's global pool an answer's renders queue
/// behind the window worker's HDBSCAN and the publisher's renders (query p99 4-6 times its
/// p50 under a two-camera flood). Without the pool (it failed to start), on the caller's.
pub(super) fn on_query_pool<T: Send>(work: impl FnOnce() -> T + Send) -> T {
    static POOL: std::sync::OnceLock<Option<rayon::ThreadPool>> = std::sync::OnceLock::new();
    let pool = POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(QUERY_THREADS)
            .thread_name(|i| format!("gf-query-{i}"))
            .build()
            .map_err(|e| tracing::warn!("no query thread pool ({e}): answers share rayon's"))
            .ok()
    });
    match pool {
        Some(pool) => pool.install(work),
        None => work(),
    }
}

/// The `Refer` service: CDR in, CDR out.
pub fn handle_refer(
    shared: &Mutex<Shared>,
    request: &[u8],
) -> std::result::Result<Vec<u8>, String> {
    let request: ReferRequest = cdr::decode(request).map_err(|e| e.to_string())?;
    cdr::encode(&refer_request(shared, &request)).map_err(|e| e.to_string())
}

/// A referring answer as JSON: ids, confidences, boxes, candidates and the reasoning (clouds and
/// masks are the service's).
pub(super) fn refer_json(
    shared: &Mutex<Shared>,
    body: &str,
) -> std::result::Result<serde_json::Value, String> {
    let body: serde_json::Value = serde_json::from_str(body).map_err(|e| {
        format!("the refer API takes JSON like {{\"expression\": \"the chair\"}}: {e}")
    })?;
    let expression = body["expression"]
        .as_str()
        .ok_or("the refer API needs a string `expression`")?;
    let request = ReferRequest {
        expression: expression.into(),
        max_targets: body["max_targets"].as_u64().unwrap_or(0) as u32,
        reasoner: body["reasoner"].as_str().unwrap_or("").into(),
        ..ReferRequest::default()
    };
    let r = refer_request(shared, &request);
    Ok(serde_json::json!({
        "success": r.success,
        "message": r.message,
        "instance_ids": r.instance_ids,
        "confidences": r.confidences,
        "boxes": r.boxes,
        "candidates": r.candidates,
        "reasoner_used": r.reasoner_used,
        "trace": r.trace,
        "target_points": r.target_cloud.width,
        "views_with_masks": r.view_masks.len(),
    }))
}
