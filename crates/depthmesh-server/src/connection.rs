//! One client's WebSocket: the hello that opens a session, frames in,
//! verdicts and status images out, and the end that writes the session's
//! files and sends its summary and mesh. A client that breaks a rule is
//! sent an `Error` saying which and disconnected; its session still writes
//! what it mapped.

use crate::protocol::{
    tagged, valid_session_name, ClientMessage, FrameMessage, ServerMessage, Verdict, MESH_MAGIC,
};
use crate::server::{Entry, Shared};
use crate::view::feed::Feed;
use crate::view::hub::ViewHub;
use crate::worker::{Inbox, Job, Out, Progress, Worker};
use axum::extract::ws::{Message, WebSocket};
use depthmesh::session::run_files::RunFiles;
use depthmesh::session::{Session, SessionConfig};
use depthmesh::store::checkpoints;
use futures_util::stream::{SplitSink, SplitStream};
use futures_util::{SinkExt, StreamExt};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{SystemTime, UNIX_EPOCH};
use tokio::sync::mpsc;
use tokio::time::timeout;

/// A session's store, in its folder (servers with stores).
const STORE: &str = "map.store";

type Tx = SplitSink<WebSocket, Message>;
type Rx = SplitStream<WebSocket>;

/// An open session, as its connection sees it.
struct Opened {
    name: String,
    /// A continued session: the last frame it had mapped.
    last_frame: Option<u64>,
    inbox: Arc<Inbox>,
    out: mpsc::UnboundedReceiver<Out>,
    realtime: bool,
}

/// Serves one client until its session ends.
pub async fn handle(socket: WebSocket, shared: Arc<Shared>) {
    let (mut tx, mut rx) = socket.split();
    let idle = shared.options.limits.idle_timeout;
    let first = match timeout(idle, rx.next()).await {
        Ok(Some(Ok(Message::Text(text)))) => Ok(text.to_string()),
        Ok(Some(Ok(_))) => Err("the first message must be a JSON hello".to_string()),
        Ok(_) => return,
        Err(_) => Err(format!("no hello within {} s", idle.as_secs())),
    };
    let opened = first.and_then(|text| open(&shared, &text));
    let mut opened = match opened {
        Ok(o) => o,
        Err(message) => return refuse(&mut tx, message).await,
    };
    let welcome = ServerMessage::Welcome {
        session: opened.name.clone(),
        window: shared.options.limits.window,
        last_frame: opened.last_frame,
    };
    let _ = send_json(&mut tx, &welcome).await;
    serve(&shared, &mut opened, &mut tx, &mut rx).await;
    let mut sessions = shared.sessions.lock().expect("sessions lock");
    if let Some(e) = sessions.get_mut(&opened.name) {
        e.inbox = None;
    }
}

/// Relays frames to the session's thread and its results to the client
/// until the session ends.
async fn serve(shared: &Shared, o: &mut Opened, tx: &mut Tx, rx: &mut Rx) {
    let limits = shared.options.limits;
    let mut shutdown = shared.shutdown.clone();
    // Once the session is ending, no more frames are read.
    let mut ending = false;
    // After an error the client is only told that, not the summary.
    let mut refused = false;
    loop {
        tokio::select! {
            incoming = timeout(limits.idle_timeout, rx.next()), if !ending => {
                let problem = match incoming {
                    Err(_) => Some(format!("idle for {} s", limits.idle_timeout.as_secs())),
                    // The client is gone: end the session with what it sent.
                    Ok(None) | Ok(Some(Err(_))) | Ok(Some(Ok(Message::Close(_)))) => {
                        refused = true;
                        None
                    }
                    Ok(Some(Ok(message))) => match accept(o, message, limits.window) {
                        Ok(Accepted::Frame(dropped)) => {
                            if let Some(frame) = dropped {
                                let v = dropped_verdict(frame);
                                let _ = send_json(tx, &ServerMessage::Verdict(v)).await;
                            }
                            continue;
                        }
                        Ok(Accepted::Ignored) => continue,
                        Ok(Accepted::End) => None,
                        Err(message) => Some(message),
                    },
                };
                if let Some(message) = problem {
                    let _ = send_json(tx, &ServerMessage::Error { message }).await;
                    refused = true;
                }
                o.inbox.push(Job::End, false);
                ending = true;
            }
            out = o.out.recv() => {
                let done = relay(shared, o, tx, out, refused).await;
                if done {
                    break;
                }
            }
            _ = async { let _ = shutdown.wait_for(|s| *s).await; }, if !ending => {
                o.inbox.push(Job::End, false);
                ending = true;
            }
        }
    }
    let _ = tx.close().await;
}

/// What a client's message asked for.
enum Accepted {
    /// A frame was queued; a frame dropped in its favour, if any.
    Frame(Option<u64>),
    /// Nothing to do (a ping).
    Ignored,
    /// The client has no more frames.
    End,
}

/// Checks and queues one message from the client.
fn accept(o: &Opened, message: Message, window: u32) -> Result<Accepted, String> {
    match message {
        Message::Binary(bytes) => {
            let frame = FrameMessage::decode(&bytes).map_err(|e| e.to_string())?;
            if !o.realtime && o.inbox.waiting_frames() >= window as usize {
                return Err(format!(
                    "more than {window} frames in flight: wait for verdicts"
                ));
            }
            Ok(Accepted::Frame(o.inbox.push(Job::Frame(frame), o.realtime)))
        }
        Message::Text(text) => match serde_json::from_str::<ClientMessage>(&text) {
            Ok(ClientMessage::End) => Ok(Accepted::End),
            Ok(ClientMessage::Hello { .. }) => Err("the session is already open".into()),
            Err(e) => Err(format!("malformed message: {e}")),
        },
        Message::Ping(_) | Message::Pong(_) | Message::Close(_) => Ok(Accepted::Ignored),
    }
}

/// Sends one result of the session's thread; whether the session is over.
async fn relay(shared: &Shared, o: &Opened, tx: &mut Tx, out: Option<Out>, refused: bool) -> bool {
    match out {
        Some(Out::Verdict(v)) => {
            let _ = send_json(tx, &ServerMessage::Verdict(v)).await;
            false
        }
        Some(Out::Binary(b)) => {
            let _ = tx.send(Message::Binary(b.into())).await;
            false
        }
        Some(Out::Finished(summary)) => {
            eprintln!(
                "session {}: finished, files in {}",
                o.name,
                dir(shared, &o.name).display()
            );
            if !refused {
                let _ = send_json(tx, &ServerMessage::Finished { summary }).await;
                let path = dir(shared, &o.name).join("mesh.ply");
                if let Ok(ply) = tokio::fs::read(&path).await {
                    let _ = tx
                        .send(Message::Binary(tagged(MESH_MAGIC, 0, &ply).into()))
                        .await;
                }
            }
            true
        }
        Some(Out::Fatal(message)) => {
            eprintln!("session {}: {message}", o.name);
            if !refused {
                let _ = send_json(tx, &ServerMessage::Error { message }).await;
            }
            true
        }
        None => true,
    }
}

/// The verdict on a frame dropped to keep up.
fn dropped_verdict(frame: u64) -> Verdict {
    Verdict {
        frame,
        pose: None,
        lost: None,
        weak_directions: 0,
        dropped: true,
        ms: 0.0,
        elements: 0,
    }
}

/// `OUT/<name>`; `name` was checked by [`valid_session_name`].
fn dir(shared: &Shared, name: &str) -> std::path::PathBuf {
    shared.options.out.join(name)
}

/// Checks a hello and opens its session: the token, the name, the camera,
/// the session limit; starts the session's thread.
fn open(shared: &Shared, text: &str) -> Result<Opened, String> {
    let hello: ClientMessage =
        serde_json::from_str(text).map_err(|e| format!("malformed hello: {e}"))?;
    let ClientMessage::Hello {
        token,
        session,
        intrinsics,
        track,
        realtime,
        status_every,
        resume,
    } = hello
    else {
        return Err("the first message must be a hello".into());
    };
    if !shared.authorised(&token) {
        return Err("wrong token".into());
    }
    let name = session.unwrap_or_else(generated_name);
    if !valid_session_name(&name) {
        return Err(format!(
            "session name {name:?}: use 1 to 64 letters, digits, '-' or '_'"
        ));
    }
    let k = intrinsics;
    k.validate().map_err(|e| e.to_string())?;
    let limits = &shared.options.limits;
    if k.pixel_count() as u64 > limits.max_frame_pixels {
        return Err(format!(
            "{}×{} frames exceed the server's limit of {} pixels",
            k.width, k.height, limits.max_frame_pixels
        ));
    }
    let config = SessionConfig {
        intrinsics: k,
        map: (shared.options.map)(k),
        tracking: track.then(|| shared.options.tracker.clone()),
    };
    let (session, checkpoints) = match shared.options.checkpoint_every {
        Some(every) => {
            // Checked again below, when the session is registered; here so
            // that a live session's store is not opened twice.
            if mapping_now(shared, &name) {
                return Err(format!(
                    "session {name} is mapping now: choose another name"
                ));
            }
            let folder = dir(shared, &name);
            std::fs::create_dir_all(&folder)
                .map_err(|e| format!("cannot prepare the session's folder: {e}"))?;
            // The session's frames are whatever its client sends under its name.
            let source = serde_json::json!({ "session": name });
            let (session, checkpoints, _) =
                checkpoints::start(&folder.join(STORE), config, source, every, resume)
                    .map_err(|e| format!("session {name}: {e}"))?;
            (session, Some(checkpoints))
        }
        None if resume => {
            return Err("this server keeps no stores: sessions cannot be continued".into())
        }
        None => (Session::new(config).map_err(|e| e.to_string())?, None),
    };
    let last_frame = session.records().last().map(|r| r.frame as u64);
    let progress = Arc::new(Mutex::new(Progress::default()));
    let inbox = Arc::new(Inbox::default());
    let view = Arc::new(ViewHub::new(view_info(&name, &session)));
    {
        let mut sessions = shared.sessions.lock().expect("sessions lock");
        let live = sessions.values().filter(|e| e.inbox.is_some()).count();
        if live >= limits.max_sessions {
            return Err(format!(
                "the server maps {} sessions at most; try later",
                limits.max_sessions
            ));
        }
        if sessions.get(&name).is_some_and(|e| e.inbox.is_some()) {
            return Err(format!(
                "session {name} is mapping now: choose another name"
            ));
        }
        sessions.insert(
            name.clone(),
            Entry {
                map: session.backend().mapper().name(),
                progress: progress.clone(),
                inbox: Some(inbox.clone()),
                external: false,
                view: view.clone(),
            },
        );
    }
    let files = match RunFiles::create(&dir(shared, &name), &session) {
        Ok(f) => f,
        Err(e) => {
            shared.sessions.lock().expect("sessions lock").remove(&name);
            return Err(format!("cannot prepare the session's folder: {e}"));
        }
    };
    let worker = Worker {
        session,
        checkpoints,
        files,
        depth_range: shared.options.depth_range,
        max_pixels: limits.max_frame_pixels,
        status_every,
        progress,
        feed: Feed::new(view, &k),
        bytes_in: 0,
    };
    let (out_tx, out_rx) = mpsc::unbounded_channel();
    let thread_inbox = inbox.clone();
    std::thread::Builder::new()
        .name(format!("session {name}"))
        .spawn(move || worker.run(thread_inbox, out_tx))
        .map_err(|e| format!("cannot start the session: {e}"))?;
    eprintln!(
        "session {name}: {}×{} frames, tracking {track}",
        k.width, k.height
    );
    Ok(Opened {
        last_frame,
        name,
        inbox,
        out: out_rx,
        realtime,
    })
}

/// Whether the session `name` is mapping now.
fn mapping_now(shared: &Shared, name: &str) -> bool {
    let sessions = shared.sessions.lock().expect("sessions lock");
    sessions.get(name).is_some_and(|e| e.inbox.is_some())
}

/// What a viewer is told of a session first: its back-end, its camera,
/// and how the page should group the map's parts into drawn meshes (see
/// [`Session::part_group_bits`]).
pub(crate) fn view_info(name: &str, session: &Session) -> serde_json::Value {
    let map = session.backend().mapper().name();
    let group_bits = session.part_group_bits();
    let k = session.config().intrinsics;
    serde_json::json!({
        "session": name,
        "map": map,
        "group_bits": group_bits,
        // Plane patches are unoriented, each with its own vertices: joining
        // neighbours' shared corners would average opposite normals.
        "join": map != "planes",
        "camera": {"width": k.width, "height": k.height, "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy},
    })
}

/// A fresh session name: the time and a counter.
fn generated_name() -> String {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let seconds = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    format!("s{seconds}-{}", COUNTER.fetch_add(1, Ordering::Relaxed))
}

async fn send_json(tx: &mut Tx, message: &ServerMessage) -> Result<(), axum::Error> {
    let text = serde_json::to_string(message).expect("messages serialise");
    tx.send(Message::Text(text.into())).await
}

/// Tells the client why it is refused and closes.
async fn refuse(tx: &mut Tx, message: String) {
    let _ = send_json(tx, &ServerMessage::Error { message }).await;
    let _ = tx.close().await;
}
