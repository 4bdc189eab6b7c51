//! A viewer without a browser (`depthmesh watch`): connects to a session's
//! view like the page does, keeps the parts' triangle counts and the bytes
//! received, and stops when the session ends. For scripts and benchmarks
//! that need what a viewer gets without drawing it.

use crate::client::ws_url;
use crate::view::wire::PART_MAGIC;
use futures_util::StreamExt;
use serde_json::Value;
use std::collections::HashMap;
use std::time::Duration;
use tokio_tungstenite::tungstenite::protocol::WebSocketConfig;
use tokio_tungstenite::tungstenite::Message;

/// What a viewer received from a session.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Watched {
    /// Bytes of every message received.
    pub bytes: u64,
    /// Messages received.
    pub messages: u64,
    /// Part messages received (versions, deletions included).
    pub part_messages: u64,
    /// Parts held at the end.
    pub parts: usize,
    /// Triangles of the parts held at the end.
    pub triangles: u64,
    /// The last figures (frames, fps, …).
    pub figures: Value,
    /// The session's summary, if it ended while watched.
    pub ended: Option<Value>,
}

/// Watches session `session` on `server` (`http://HOST:PORT`) until it
/// ends, or until nothing arrives for `quiet`.
pub async fn watch(
    server: &str,
    token: &str,
    session: &str,
    quiet: Duration,
) -> Result<Watched, String> {
    let url = format!("{}/view/{session}?token={}", ws_url(server)?, escape(token));
    let config = WebSocketConfig::default().max_message_size(Some(1 << 30));
    let (mut ws, _) = tokio_tungstenite::connect_async_with_config(&url, Some(config), false)
        .await
        .map_err(|e| format!("cannot watch session {session} at {server}: {e}"))?;
    let mut held: HashMap<[i32; 3], u64> = HashMap::new();
    let mut w = Watched::default();
    loop {
        let message = match tokio::time::timeout(quiet, ws.next()).await {
            Err(_) => break,
            Ok(None) => break,
            Ok(Some(m)) => m.map_err(|e| format!("session {session}: {e}"))?,
        };
        w.messages += 1;
        match message {
            Message::Binary(b) => {
                w.bytes += b.len() as u64;
                if b.len() >= 28 && &b[..4] == PART_MAGIC {
                    w.part_messages += 1;
                    let word = |o: usize| i32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
                    let key = [word(4), word(8), word(12)];
                    let triangles = word(24) as u32 as u64 / 3;
                    if triangles == 0 {
                        held.remove(&key);
                    } else {
                        held.insert(key, triangles);
                    }
                }
            }
            Message::Text(t) => {
                w.bytes += t.len() as u64;
                let v: Value = serde_json::from_str(&t)
                    .map_err(|e| format!("session {session}: malformed message: {e}"))?;
                match v["type"].as_str() {
                    Some("figures") => w.figures = v,
                    Some("ended") => {
                        w.ended = Some(v);
                        break;
                    }
                    _ => {}
                }
            }
            Message::Close(_) => break,
            _ => {}
        }
    }
    w.parts = held.len();
    w.triangles = held.values().sum();
    Ok(w)
}

/// `text` with everything but unreserved URL characters percent-encoded.
fn escape(text: &str) -> String {
    text.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'~' => {
                char::from(b).to_string()
            }
            _ => format!("%{b:02X}"),
        })
        .collect()
}
