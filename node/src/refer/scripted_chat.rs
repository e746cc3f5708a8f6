//! A scripted chat server for the VLM path's tests and `bench soak`: it speaks the OpenAI chat
//! completions protocol over plain HTTP on loopback and answers each connection with the next
//! scripted reply. It is no model and never appears in an accuracy figure; [`vlm_faults`] is the
//! list of ways a VLM server fails that both exercise.
use std::time::Duration;

/// One scripted reply of [`ScriptedChatServer`]: HTTP status, body, and a delay before answering.
#[derive(Debug, Clone)]
pub struct ScriptedReply {
    pub status: u16,
    pub body: String,
    pub delay: Duration,
    /// When set, the body is sent this many bytes at a time with `delay` between chunks (a slow
    /// drip) instead of after one `delay`.
    pub drip_bytes: Option<usize>,
}

impl ScriptedReply {
    /// A 200 chat completions response whose message content is `content`.
    pub fn content(content: &str) -> Self {
        let body = serde_json::json!({
            "id": "scripted",
            "object": "chat.completion",
            "choices": [{
                "index": 0,
                "message": {"role": "assistant", "content": content},
                "finish_reason": "stop",
            }],
        })
        .to_string();
        Self {
            status: 200,
            body,
            delay: Duration::ZERO,
            drip_bytes: None,
        }
    }
}

/// A scripted test server that speaks the OpenAI chat completions protocol over plain HTTP on
/// loopback: each request gets the next scripted reply, and request bodies are recorded. It is
/// what the VLM client's tests talk to; it is no model and never appears in an accuracy figure.
#[derive(Debug)]
pub struct ScriptedChatServer {
    /// Base URL as the node's `refer.vlm.endpoint` takes it (`http://127.0.0.1:<port>/v1`).
    pub url: String,
    pub requests: std::sync::Arc<std::sync::Mutex<Vec<(String, String)>>>,
    replies: std::sync::mpsc::SyncSender<ScriptedReply>,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    accepting: std::sync::Mutex<Option<std::thread::JoinHandle<()>>>,
}

impl ScriptedChatServer {
    /// Listen on a free loopback port and answer connections with `replies`, in order.
    pub fn start(replies: Vec<ScriptedReply>) -> std::io::Result<Self> {
        let server = Self::listen()?;
        for reply in replies {
            server.push(reply);
        }
        Ok(server)
    }

    /// Queue the reply for the next connection not yet answered (waits while [`REPLIES_QUEUED`]
    /// are queued).
    pub fn push(&self, reply: ScriptedReply) {
        // The accept thread only stops when this server is dropped.
        let _ = self.replies.send(reply);
    }

    /// Listen on a free loopback port; connections wait for replies [`Self::push`]ed later.
    pub fn listen() -> std::io::Result<Self> {
        use std::io::{BufRead, BufReader, Read};
        use std::sync::atomic::{AtomicBool, Ordering};
        let listener = std::net::TcpListener::bind("127.0.0.1:0")?;
        let port = listener.local_addr()?.port();
        // Polled, so that `close` can stop accepting and close the port.
        listener.set_nonblocking(true)?;
        let requests = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let recorded = requests.clone();
        let (replies, scripted) = std::sync::mpsc::sync_channel::<ScriptedReply>(REPLIES_QUEUED);
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let stopped = stop.clone();
        let accepting = std::thread::spawn(move || {
            while !stopped.load(Ordering::Relaxed) {
                let stream = match listener.accept() {
                    Ok((stream, _)) => stream,
                    Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                        std::thread::sleep(Duration::from_millis(2));
                        continue;
                    }
                    Err(_) => return,
                };
                if stream.set_nonblocking(false).is_err() {
                    continue;
                }
                let Ok(reply) = scripted.recv() else { return };
                let Ok(read_half) = stream.try_clone() else {
                    continue;
                };
                let mut reader = BufReader::new(read_half);
                let mut request_line = String::new();
                let _ = reader.read_line(&mut request_line);
                let mut length = 0usize;
                loop {
                    let mut line = String::new();
                    if reader.read_line(&mut line).unwrap_or(0) == 0 || line == "\r\n" {
                        break;
                    }
                    if let Some((name, value)) = line.split_once(':') {
                        if name.eq_ignore_ascii_case("content-length") {
                            length = value.trim().parse().unwrap_or(0);
                        }
                    }
                }
                let mut body = vec![0u8; length];
                let _ = reader.read_exact(&mut body);
                if let Ok(mut r) = recorded.lock() {
                    r.push((
                        request_line.trim().to_owned(),
                        String::from_utf8_lossy(&body).into_owned(),
                    ));
                }
                // Answered on its own thread: a slow reply does not hold up the next one.
                std::thread::spawn(move || answer(stream, &reply));
            }
        });
        Ok(Self {
            url: format!("http://127.0.0.1:{port}/v1"),
            requests,
            replies,
            stop,
            accepting: std::sync::Mutex::new(Some(accepting)),
        })
    }

    /// Stop accepting and close the port: a client's next connection is refused (the server
    /// that went away). Replies already being written still finish.
    pub fn close(&self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        let handle = self.accepting.lock().ok().and_then(|mut h| h.take());
        if let Some(handle) = handle {
            let _ = handle.join();
        }
    }
}

impl Drop for ScriptedChatServer {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
    }
}

/// Write `reply` to `stream`: after its delay, or a few bytes per delay (a slow drip).
fn answer(mut stream: std::net::TcpStream, reply: &ScriptedReply) {
    use std::io::Write;
    let response = format!(
        "HTTP/1.1 {} Scripted\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{}",
        reply.status,
        reply.body.len(),
        reply.body
    );
    match reply.drip_bytes {
        None => {
            std::thread::sleep(reply.delay);
            let _ = stream.write_all(response.as_bytes());
        }
        Some(chunk) => {
            for part in response.as_bytes().chunks(chunk.max(1)) {
                if stream
                    .write_all(part)
                    .and_then(|()| stream.flush())
                    .is_err()
                {
                    break;
                }
                std::thread::sleep(reply.delay);
            }
        }
    }
}

/// Replies waiting for their connection at most.
pub const REPLIES_QUEUED: usize = 64;

/// The client timeout the delays of [`vlm_faults`] are scripted against.
pub const FAULT_TIMEOUT_SECS: f64 = 0.5;

/// One way a VLM server fails, and words the fallback's trace must give as the reason.
#[derive(Debug, Clone)]
pub struct VlmFault {
    pub name: &'static str,
    pub reply: ScriptedReply,
    pub reason: &'static str,
}

/// After the scripted faults, the server closes its port ([`ScriptedChatServer::close`]): this is
/// what the fallback's trace must give for the refused connection.
pub const REFUSED_REASON: &str = "request failed";

/// Every scripted fault (a client with [`FAULT_TIMEOUT_SECS`]): each must be answered by the
/// built-in reasoner and flagged. `candidate` is a valid id, `two` a pair of them.
pub fn vlm_faults(candidate: &str, two: [&str; 2]) -> Vec<VlmFault> {
    let valid = format!(r#"{{"ids": ["{candidate}"]}}"#);
    let fault = |name, reply, reason| VlmFault {
        name,
        reply,
        reason,
    };
    vec![
        fault(
            "timeout",
            ScriptedReply {
                delay: Duration::from_millis(1500),
                ..ScriptedReply::content(&valid)
            },
            "did not answer",
        ),
        fault(
            "HTTP 500",
            ScriptedReply {
                status: 500,
                body: "overloaded".into(),
                delay: Duration::ZERO,
                drip_bytes: None,
            },
            "HTTP 500",
        ),
        fault(
            "non-JSON",
            ScriptedReply::content("the second chair, I think"),
            "not the expected JSON",
        ),
        fault(
            "body not JSON",
            ScriptedReply {
                status: 200,
                body: "<html>".into(),
                delay: Duration::ZERO,
                drip_bytes: None,
            },
            "not the expected JSON",
        ),
        fault(
            "outside the set",
            ScriptedReply::content(r#"{"ids": ["inst_999999"]}"#),
            "not a candidate",
        ),
        fault(
            "wrong count",
            ScriptedReply::content(&format!(r#"{{"ids": ["{}", "{}"]}}"#, two[0], two[1])),
            "asks for",
        ),
        fault("none", ScriptedReply::content(r#"{"ids": []}"#), "asks for"),
        fault(
            // A valid answer, 16 bytes every 50 ms: the whole request, not each read, is timed.
            "slow drip",
            ScriptedReply {
                delay: Duration::from_millis(50),
                drip_bytes: Some(16),
                ..ScriptedReply::content(&valid)
            },
            "did not answer",
        ),
        fault(
            // 10 MB of content: refused at the client's body limit (1 MiB), never held whole.
            "10 MB answer",
            ScriptedReply::content(&"x".repeat(10 << 20)),
            "larger than",
        ),
    ]
}
