//! End-to-end tests live in tests/; this holds what several of them share.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The repository's root.
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Run `script` with the project's test venv (`make setup`) and return its stdout; panics with
/// its stderr when it fails.
pub fn venv_python(script: &str) -> Vec<u8> {
    let python = root().join(".venv/bin/python");
    let output = Command::new(&python)
        .arg("-c")
        .arg(script)
        .output()
        .unwrap_or_else(|e| panic!("{}: {e} (run `make setup`)", python.display()));
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    output.stdout
}

/// One scripted reply of [`ScriptedChatServer`]: HTTP status, body, and a delay before answering.
#[derive(Debug, Clone)]
pub struct ScriptedReply {
    pub status: u16,
    pub body: String,
    pub delay: std::time::Duration,
    /// When set, the body is sent this many bytes at a time with `delay` between chunks (a slow
    /// drip) instead of after one `delay`.
    pub drip_bytes: Option<usize>,
}

impl ScriptedReply {
    /// A 200 chat completions response whose message content is `content`.
    pub fn content(content: &str) -> Self {
        let body = format!(
            r#"{{"id":"scripted","object":"chat.completion","choices":[{{"index":0,"message":{{"role":"assistant","content":{}}},"finish_reason":"stop"}}]}}"#,
            json_string(content)
        );
        Self {
            status: 200,
            body,
            delay: std::time::Duration::ZERO,
            drip_bytes: None,
        }
    }
}

fn json_string(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// A scripted test server that speaks the OpenAI chat completions protocol over plain HTTP on
/// loopback: each request gets the next scripted reply, and request bodies are recorded. It is
/// what the VLM client's tests talk to; it is no model and never appears in an accuracy figure.
#[derive(Debug)]
pub struct ScriptedChatServer {
    /// Base URL as the node's `refer.vlm.endpoint` takes it (`http://127.0.0.1:<port>/v1`).
    pub url: String,
    pub requests: std::sync::Arc<std::sync::Mutex<Vec<(String, String)>>>,
}

impl ScriptedChatServer {
    pub fn start(replies: Vec<ScriptedReply>) -> Self {
        use std::io::{BufRead, BufReader, Read, Write};
        let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind loopback");
        let port = listener.local_addr().expect("local address").port();
        let requests = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let recorded = requests.clone();
        std::thread::spawn(move || {
            for (reply, stream) in replies.into_iter().zip(listener.incoming()) {
                let Ok(mut stream) = stream else { return };
                let mut reader = BufReader::new(stream.try_clone().expect("clone stream"));
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
        });
        Self {
            url: format!("http://127.0.0.1:{port}/v1"),
            requests,
        }
    }
}
