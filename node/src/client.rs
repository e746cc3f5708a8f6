//! A client of a running node over zenoh, as ROS 2 tools and `groupforward query` reach it: its
//! rmw_zenoh services (CDR request, attachment, reply) and its JSON API.

use std::time::{Duration, Instant};

use groupforward_msgs::rmw_zenoh::{self, Attachment};
use groupforward_msgs::{cdr, RosService};
use zenoh::Wait;

use crate::transport::TransportError;

#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error("the node did not {0} within {1:?}")]
    Timeout(&'static str, Duration),
    #[error("{0}")]
    Protocol(String),
}

pub type Result<T> = std::result::Result<T, ClientError>;

/// The payload of the first reply to a get, or the error the replier sent.
fn first_reply(
    get: zenoh::session::SessionGetBuilder<'_, '_, zenoh::handlers::DefaultHandler>,
    what: &'static str,
    timeout: Duration,
) -> Result<Vec<u8>> {
    let replies = get
        .timeout(timeout)
        .wait()
        .map_err(|e| ClientError::Protocol(e.to_string()))?;
    let reply = replies
        .recv_timeout(timeout)
        .map_err(|e| ClientError::Protocol(e.to_string()))?
        .ok_or(ClientError::Timeout(what, timeout))?;
    match reply.result() {
        Ok(sample) => Ok(sample.payload().to_bytes().into_owned()),
        Err(e) => Err(ClientError::Protocol(format!(
            "{what}: error reply {}",
            String::from_utf8_lossy(&e.payload().to_bytes())
        ))),
    }
}

/// One JSON API request through zenoh.
pub fn query_json(
    session: &zenoh::Session,
    key: &str,
    timeout: Duration,
) -> Result<serde_json::Value> {
    let payload = first_reply(session.get(key), "answer the JSON API", timeout)?;
    serde_json::from_slice(&payload)
        .map_err(|e| ClientError::Protocol(format!("JSON API answered non-JSON: {e}")))
}

/// Call an rmw_zenoh service as a ROS 2 client would: a get on the service key with a CDR request
/// and an attachment.
pub fn call_service<S: RosService>(
    session: &zenoh::Session,
    domain_id: u32,
    service_name: &str,
    request: &S::Request,
    timeout: Duration,
) -> Result<S::Response> {
    let payload = cdr::encode(request).map_err(|e| ClientError::Protocol(e.to_string()))?;
    let response = call_service_raw::<S>(session, domain_id, service_name, payload, timeout)?;
    cdr::decode(&response).map_err(|e| ClientError::Protocol(e.to_string()))
}

/// [`call_service`] with the request's CDR bytes as they are (well formed or not), returning the
/// response's bytes.
pub fn call_service_raw<S: RosService>(
    session: &zenoh::Session,
    domain_id: u32,
    service_name: &str,
    payload: Vec<u8>,
    timeout: Duration,
) -> Result<Vec<u8>> {
    let hash = groupforward_msgs::idl::type_hash(S::TYPE_NAME).map_err(TransportError::from)?;
    let key = rmw_zenoh::data_key(domain_id, service_name, S::TYPE_NAME, &hash)
        .map_err(TransportError::from)?;
    let attachment = Attachment {
        sequence_number: 1,
        source_timestamp: 0,
        source_gid: rmw_zenoh::gid_for_token(&key),
    };
    let get = session
        .get(key)
        .payload(payload)
        .attachment(attachment.encode());
    first_reply(get, "answer the service", timeout)
}

/// Poll `check` every 20 ms until it returns `Some`, or fail after `timeout`.
pub fn wait_for<T>(
    what: &'static str,
    timeout: Duration,
    mut check: impl FnMut() -> Option<T>,
) -> Result<T> {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(value) = check() {
            return Ok(value);
        }
        if Instant::now() >= deadline {
            return Err(ClientError::Timeout(what, timeout));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}
