//! A viewer's WebSocket (`/ws/view/NAME?token=T`): the session's
//! description, then everything pending for the viewer whenever there is
//! some. The browser only listens; a close from it ends the viewer.
//!
//! Text messages are JSON with a `type`: `info` (back-end, camera, how
//! parts group), `figures` (frames, fps, triangles, rates, tracking state,
//! the sensor's pose), `trail` (trajectory points from index `from`, each
//! `[x, y, z, lost]`), `ended` (the session's summary and final triangle
//! count). Binary messages are parts and images (see [`super::wire`]).

use super::hub::{Pending, ViewHub, Viewer};
use crate::server::Shared;
use crate::worker::{Inbox, Job};
use axum::extract::ws::{Message, WebSocket};
use futures_util::stream::SplitSink;
use futures_util::{SinkExt, StreamExt};
use serde_json::{json, Value};
use std::sync::Arc;

type Tx = SplitSink<WebSocket, Message>;

/// Serves one viewer of `hub` until it leaves or the server stops;
/// `inbox` is the session's queue while it maps, to ask for a
/// publication now rather than at its next frame.
pub async fn watch(
    socket: WebSocket,
    shared: Arc<Shared>,
    hub: Arc<ViewHub>,
    inbox: Option<Arc<Inbox>>,
) {
    let (mut tx, mut rx) = socket.split();
    let mut info = hub.info.clone();
    info["type"] = json!("info");
    if send_text(&mut tx, &info).await.is_err() {
        return;
    }
    let viewer = hub.join();
    if let Some(inbox) = inbox {
        inbox.push(Job::Publish, false);
    }
    let mut shutdown = shared.shutdown.clone();
    loop {
        tokio::select! {
            _ = viewer.ready.notified() => {
                if send_pending(&mut tx, &hub, &viewer).await.is_err() {
                    break;
                }
            }
            incoming = rx.next() => match incoming {
                Some(Ok(Message::Close(_))) | Some(Err(_)) | None => break,
                Some(Ok(_)) => {}
            },
            _ = async { let _ = shutdown.wait_for(|s| *s).await; } => break,
        }
    }
    hub.leave(&viewer);
    let _ = tx.close().await;
}

/// Sends what is pending for `viewer`: parts, trajectory, figures, images,
/// the end.
async fn send_pending(tx: &mut Tx, hub: &ViewHub, viewer: &Viewer) -> Result<(), axum::Error> {
    let Pending {
        parts,
        trail_from,
        figures,
        images,
        ended,
    } = viewer.take();
    for part in parts.values() {
        tx.feed(Message::Binary(part.message())).await?;
    }
    // Copied out so that the hub's lock is not held across a send.
    let (trail, figure_values, image_bytes, summary) = hub.with_shown(|s| {
        (
            s.trail[trail_from.min(s.trail.len())..].to_vec(),
            figures.then(|| s.figures.clone()),
            s.images
                .clone()
                .map(Some)
                .into_iter()
                .zip(images)
                .map(|(i, wanted)| i.flatten().filter(|_| wanted))
                .collect::<Vec<_>>(),
            s.ended.clone().filter(|_| ended),
        )
    });
    if !trail.is_empty() {
        let to = trail_from + trail.len();
        send_text(
            tx,
            &json!({"type": "trail", "from": trail_from, "points": trail}),
        )
        .await?;
        viewer.sent_trail(to);
    }
    for image in image_bytes.into_iter().flatten() {
        tx.feed(Message::Binary(image.to_vec().into())).await?;
    }
    if let Some(mut f) = figure_values {
        f["type"] = json!("figures");
        send_text(tx, &f).await?;
    }
    if let Some(mut summary) = summary {
        summary["type"] = json!("ended");
        send_text(tx, &summary).await?;
    }
    tx.flush().await
}

async fn send_text(tx: &mut Tx, value: &Value) -> Result<(), axum::Error> {
    tx.send(Message::Text(value.to_string().into())).await
}
