//! What the node serves: the list / get / save / load services, the `Refer` service ([`refer`]),
//! the JSON API, and their declaration; the state they share with the node is [`shared`].

mod refer;
mod shared;

use std::sync::{Arc, Mutex};

use groupforward_msgs::gf_msgs::{
    GetInstanceRequest, GetInstanceResponse, ListInstancesRequest, ListInstancesResponse,
    MapPathRequest, MapResultResponse, NodeStatus,
};
use groupforward_msgs::rmw_zenoh::{resolve_name, Qos};
use groupforward_msgs::services::{GetInstance, ListInstances, LoadMap, Refer, SaveMap};
use groupforward_msgs::{cdr, RosMessage, RosService};

use super::error::Result;
use super::queue::InputQueue;
use crate::config::Config;
use crate::graph::persist;
use crate::ingest::{Ingest, Route};
use crate::transport::{Endpoint, Transport};
use refer::refer_json;

pub use refer::{handle_refer, refer_request};
pub use shared::{
    current_snapshot, current_snapshot_and_generation, instance_messages, instance_messages_cached,
    object_lists_cached, query_snapshot, snapshot_due, BoxCache, Shared, SNAPSHOT_DUE_SECS,
};

/// The file a `save_map` / `load_map` request names: `map.file` when it names none; inside
/// `map.directory` when one is configured (a path that would leave it is refused).
fn map_path(shared: &Shared, requested: &str) -> std::result::Result<String, String> {
    if requested.is_empty() {
        return shared
            .map_file
            .clone()
            .ok_or_else(|| "no path given and no map.file configured".to_owned());
    }
    let Some(directory) = &shared.map_directory else {
        return Ok(requested.to_owned());
    };
    let path = std::path::Path::new(requested);
    let escapes = path
        .components()
        .any(|c| matches!(c, std::path::Component::ParentDir));
    let inside = if path.is_absolute() {
        path.starts_with(directory).then(|| path.to_path_buf())
    } else {
        Some(directory.join(path))
    };
    match inside {
        Some(p) if !escapes => Ok(p.display().to_string()),
        _ => Err(format!(
            "`{requested}` is outside the map directory {} (map.directory)",
            directory.display()
        )),
    }
}

fn handle_save(shared: &Mutex<Shared>, request: &[u8]) -> std::result::Result<Vec<u8>, String> {
    let request: MapPathRequest = cdr::decode(request).map_err(|e| e.to_string())?;
    // Serialise under the lock, write outside it: a slow disk never stalls the node loop.
    let (path, bytes) = {
        let s = shared.lock().map_err(|e| e.to_string())?;
        let path = map_path(&s, &request.path);
        (path, persist::to_bytes(&s.map))
    };
    let outcome = path.and_then(|path| {
        persist::write_atomically(std::path::Path::new(&path), &bytes)
            .map(|()| format!("saved {} bytes to {path}", bytes.len()))
            .map_err(|e| e.to_string())
    });
    map_result("save_map", outcome)
}

/// A SaveMap / LoadMap response; failures are logged too.
fn map_result(
    service: &str,
    outcome: std::result::Result<String, String>,
) -> std::result::Result<Vec<u8>, String> {
    let response = match outcome {
        Ok(message) => MapResultResponse {
            success: true,
            message,
        },
        Err(message) => {
            tracing::warn!("{service} failed: {message}");
            MapResultResponse {
                success: false,
                message,
            }
        }
    };
    cdr::encode(&response).map_err(|e| e.to_string())
}

fn handle_load(shared: &Mutex<Shared>, request: &[u8]) -> std::result::Result<Vec<u8>, String> {
    let request: MapPathRequest = cdr::decode(request).map_err(|e| e.to_string())?;
    let (path, params) = {
        let s = shared.lock().map_err(|e| e.to_string())?;
        (map_path(&s, &request.path), s.map.params)
    };
    let loaded = path.and_then(|path| {
        persist::load(std::path::Path::new(&path), params)
            .map(|map| (path, map))
            .map_err(|e| e.to_string())
    });
    let outcome = match loaded {
        Ok((path, map)) => {
            let count = map.instances.len();
            shared.lock().map_err(|e| e.to_string())?.set_map(map);
            Ok(format!("loaded {count} instances from {path}"))
        }
        // The running map is untouched on any error.
        Err(message) => Err(message),
    };
    map_result("load_map", outcome)
}

fn handle_list(shared: &Mutex<Shared>, request: &[u8]) -> std::result::Result<Vec<u8>, String> {
    let request: ListInstancesRequest = cdr::decode(request).map_err(|e| e.to_string())?;
    let instances = shared
        .lock()
        .map_err(|e| e.to_string())?
        .instances
        .iter()
        .filter(|i| {
            request.label_filter.is_empty()
                || i.hypotheses
                    .first()
                    .is_some_and(|h| h.class_id.contains(&request.label_filter))
        })
        .cloned()
        .collect();
    cdr::encode(&ListInstancesResponse { instances }).map_err(|e| e.to_string())
}

fn handle_get(shared: &Mutex<Shared>, request: &[u8]) -> std::result::Result<Vec<u8>, String> {
    let request: GetInstanceRequest = cdr::decode(request).map_err(|e| e.to_string())?;
    let found = shared
        .lock()
        .map_err(|e| e.to_string())?
        .instances
        .iter()
        .find(|i| i.id == request.id)
        .cloned();
    let response = GetInstanceResponse {
        found: found.is_some(),
        instance: found.unwrap_or_default(),
        ..Default::default()
    };
    cdr::encode(&response).map_err(|e| e.to_string())
}

/// The reason a request over the bound is refused with (and the status counts it under).
pub const REQUEST_RATE_LIMITED: &str = "request_rate_limited";

/// Take a request under the node's bound on requests, or refuse it with the reason (counted).
pub fn admit(shared: &Mutex<Shared>) -> std::result::Result<(), String> {
    let mut s = shared
        .lock()
        .map_err(|_| "node state unavailable".to_owned())?;
    if s.limiter.admit(std::time::Instant::now()) {
        Ok(())
    } else {
        s.requests_limited += 1;
        Err(format!(
            "{REQUEST_RATE_LIMITED}: more requests than node.max_requests_per_second"
        ))
    }
}

fn handle_json(
    shared: &Mutex<Shared>,
    name: &str,
    body: &str,
) -> std::result::Result<String, String> {
    if name == "refer" {
        return refer_json(shared, body).map(|v| v.to_string());
    }
    let shared = shared.lock().map_err(|e| e.to_string())?;
    let value = match name {
        "status" => serde_json::to_value(&shared.status),
        "instances" => serde_json::to_value(&shared.instances),
        "scene_graph" => Ok(shared
            .scene_graph_json
            .clone()
            .unwrap_or_else(|| serde_json::json!({"nodes": [], "edges": []}))),
        other => {
            return Err(format!(
                "unknown API `{other}`; available: status, instances, scene_graph, refer"
            ))
        }
    };
    value.map(|v| v.to_string()).map_err(|e| e.to_string())
}

/// The resolved names the node declares, for logs and docs.
#[derive(Debug, Clone)]
pub struct Declared {
    pub subscriptions: Vec<Endpoint>,
    pub status: Endpoint,
    pub services: Vec<Endpoint>,
    pub json_prefix: String,
}

/// Subscribe to the inputs, and declare the status topic, services and JSON API.
pub fn declare(
    config: &Config,
    transport: &dyn Transport,
    queue: &Arc<InputQueue>,
    shared: &Arc<Mutex<Shared>>,
) -> Result<Declared> {
    let ns = &config.node.namespace;
    let name = &config.node.name;
    let mut subscriptions = Vec::new();
    for (topic, route) in Ingest::routes(&config.cameras, &config.tf) {
        let qos = match route {
            Route::TfStatic => Qos {
                transient_local: true,
                depth: 1,
                ..Qos::default()
            },
            Route::Tf => Qos::default(),
            _ => Qos::sensor_data(),
        };
        let endpoint = Endpoint::new(&resolve_name(ns, name, &topic)?, route.type_name(), qos)?;
        let queue = queue.clone();
        transport.subscribe(
            &endpoint,
            Arc::new(move |payload| queue.push(route, payload)),
        )?;
        subscriptions.push(endpoint);
    }
    let status = Endpoint::new(
        &resolve_name(ns, name, "~/status")?,
        NodeStatus::TYPE_NAME,
        Qos::default(),
    )?;
    let list = Endpoint::new(
        &resolve_name(ns, name, "~/list_instances")?,
        ListInstances::TYPE_NAME,
        Qos::default(),
    )?;
    let get = Endpoint::new(
        &resolve_name(ns, name, "~/get_instance")?,
        GetInstance::TYPE_NAME,
        Qos::default(),
    )?;
    let save = Endpoint::new(
        &resolve_name(ns, name, "~/save_map")?,
        SaveMap::TYPE_NAME,
        Qos::default(),
    )?;
    let load = Endpoint::new(
        &resolve_name(ns, name, "~/load_map")?,
        LoadMap::TYPE_NAME,
        Qos::default(),
    )?;
    let refer = Endpoint::new(
        &resolve_name(ns, name, "~/refer")?,
        Refer::TYPE_NAME,
        Qos::default(),
    )?;
    type Handler = fn(&Mutex<Shared>, &[u8]) -> std::result::Result<Vec<u8>, String>;
    let handlers: [(&Endpoint, Handler); 5] = [
        (&refer, handle_refer),
        (&save, handle_save),
        (&load, handle_load),
        (&list, handle_list),
        (&get, handle_get),
    ];
    for (endpoint, handle) in handlers {
        let s = shared.clone();
        transport.serve(
            endpoint,
            Arc::new(move |req| {
                admit(&s)?;
                handle(&s, req)
            }),
        )?;
    }
    let prefix = config.api_prefix();
    let s = shared.clone();
    transport.serve_json(
        &prefix,
        Arc::new(move |api, body| {
            // The status is a cached message: reading it costs nothing and is how a client
            // learns that it is being refused.
            if api != "status" {
                admit(&s)?;
            }
            handle_json(&s, api, &String::from_utf8_lossy(body))
        }),
    )?;
    Ok(Declared {
        subscriptions,
        status,
        services: vec![refer, list, get, save, load],
        json_prefix: prefix,
    })
}

#[cfg(test)]
mod tests;
