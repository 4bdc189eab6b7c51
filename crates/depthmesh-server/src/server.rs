//! `depthmesh serve`: one port for everything. Sensor clients open a
//! WebSocket at `/ws` and map a session each; `/api/sessions` lists the
//! sessions and `/api/sessions/NAME/mesh.(ply|glb)` downloads a session's
//! mesh, live or finished. Every request needs the token; limits bound
//! message and frame sizes, sessions and idle time, and a client that breaks
//! them is told why and disconnected while the others carry on.

use crate::connection;
use crate::view::hub::ViewHub;
use crate::web;
use crate::worker::{Inbox, Progress};
use axum::extract::ws::WebSocketUpgrade;
use axum::extract::{Path as UrlPath, Query, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use depthmesh::export::{build_assets, glb_of_assets, ExportOptions, Format, UpAxis};
use depthmesh::mesh::io::read_mesh;
use depthmesh::mesh::ply::{write_ply_to, PlyFormat};
use depthmesh::mesh::simplify::SimplifyParams;
use depthmesh::mesh::Mesh;
use depthmesh::session::MapConfig;
use depthmesh::track::TrackerConfig;
use depthmesh::Intrinsics;
use serde::Deserialize;
use serde_json::json;
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use subtle::ConstantTimeEq;
use tokio::sync::{oneshot, watch};

/// Bounds on what clients may send.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// Largest WebSocket message, bytes.
    pub max_message_bytes: usize,
    /// Largest depth image, pixels.
    pub max_frame_pixels: u64,
    /// Sessions mapping at once.
    pub max_sessions: usize,
    /// A client silent this long is disconnected (its session ends).
    pub idle_timeout: Duration,
    /// Frames a client may have in flight.
    pub window: u32,
}

impl Default for Limits {
    /// 16 MiB messages, 4 Mpixel frames (a 2048×2048 sensor), 8 sessions,
    /// 60 s of silence, 8 frames in flight.
    fn default() -> Self {
        Limits {
            max_message_bytes: 16 << 20,
            max_frame_pixels: 1 << 22,
            max_sessions: 8,
            idle_timeout: Duration::from_secs(60),
            window: 8,
        }
    }
}

/// Builds a session's map for a client's camera.
pub type MapFactory = dyn Fn(Intrinsics) -> MapConfig + Send + Sync;

/// How the server runs.
pub struct ServeOptions {
    /// Address to listen on (port 0: any free one).
    pub bind: SocketAddr,
    /// The token every client must present.
    pub token: String,
    /// Sessions write their files into `out/<session>/`.
    pub out: PathBuf,
    /// Client limits.
    pub limits: Limits,
    /// Depths outside this range (metres) are dropped.
    pub depth_range: (f32, f32),
    /// Tracking settings for sessions that ask for tracking.
    pub tracker: TrackerConfig,
    /// Each session's map, from its camera.
    pub map: Box<MapFactory>,
    /// Sessions keep their maps in a store, `out/<session>/map.store`,
    /// checkpointed every this many frames, and a client may continue a
    /// session from it (`None`: no stores).
    pub checkpoint_every: Option<u32>,
}

/// A session the server knows of.
pub(crate) struct Entry {
    /// The back-end's name.
    pub map: &'static str,
    /// Figures while it maps.
    pub progress: Arc<Mutex<Progress>>,
    /// Its thread's queue while it maps; `None` once finished.
    pub inbox: Option<Arc<Inbox>>,
    /// A view of a map made elsewhere (see [`crate::external`]): live while the server runs.
    pub external: bool,
    /// What its viewers see.
    pub view: Arc<ViewHub>,
}

/// What every request handler shares.
pub(crate) struct Shared {
    pub options: ServeOptions,
    pub sessions: Mutex<BTreeMap<String, Entry>>,
    /// Flips to true when the server is asked to stop.
    pub shutdown: watch::Receiver<bool>,
}

impl Shared {
    /// Whether `given` is the token, compared in constant time.
    pub fn authorised(&self, given: &str) -> bool {
        let expected = self.options.token.as_bytes();
        given.len() == expected.len() && bool::from(given.as_bytes().ct_eq(expected))
    }
}

/// A running server.
pub struct Server {
    /// Where it listens.
    pub addr: SocketAddr,
    pub(crate) shared: Arc<Shared>,
    stop: watch::Sender<bool>,
    task: tokio::task::JoinHandle<std::io::Result<()>>,
}

impl Server {
    /// Binds and starts serving on the current tokio runtime. A
    /// non-loopback address needs a non-empty token.
    pub async fn start(options: ServeOptions) -> std::io::Result<Server> {
        if options.token.is_empty() {
            return Err(std::io::Error::other("the token must not be empty"));
        }
        std::fs::create_dir_all(&options.out)?;
        let listener = tokio::net::TcpListener::bind(options.bind).await?;
        let addr = listener.local_addr()?;
        let (stop, shutdown) = watch::channel(false);
        let shared = Arc::new(Shared {
            options,
            sessions: Mutex::new(BTreeMap::new()),
            shutdown: shutdown.clone(),
        });
        let app = Router::new()
            .route("/", get(web::page))
            .route("/view/{name}", get(web::page))
            .route("/assets/{file}", get(web::asset))
            .route("/ws/view/{name}", get(web::view_socket))
            .route("/ws", get(upgrade))
            .route("/api/sessions", get(list))
            .route("/api/sessions/{name}/{file}", get(download))
            .with_state(shared.clone());
        let mut stopped = shutdown;
        let task = tokio::spawn(async move {
            axum::serve(listener, app)
                .with_graceful_shutdown(async move {
                    let _ = stopped.wait_for(|s| *s).await;
                })
                .await
        });
        Ok(Server {
            addr,
            shared,
            stop,
            task,
        })
    }

    /// Ends every session (each writes its files) and stops serving.
    pub async fn stop(self) -> std::io::Result<()> {
        let _ = self.stop.send(true);
        self.task.await.map_err(std::io::Error::other)?
    }
}

/// The token of a request: `Authorization: Bearer T`, or `?token=T` for
/// links a browser follows.
pub(crate) fn request_token(headers: &HeaderMap, query: &TokenQuery) -> Option<String> {
    headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "))
        .map(str::to_string)
        .or_else(|| query.token.clone())
}

/// A request's `?token=`.
#[derive(Debug, Default, Deserialize)]
pub(crate) struct TokenQuery {
    pub token: Option<String>,
}

pub(crate) fn refuse(status: StatusCode, message: &str) -> Response {
    (status, Json(json!({ "error": message }))).into_response()
}

async fn upgrade(State(shared): State<Arc<Shared>>, ws: WebSocketUpgrade) -> Response {
    let limit = shared.options.limits.max_message_bytes;
    ws.max_message_size(limit)
        .max_frame_size(limit)
        .on_upgrade(move |socket| connection::handle(socket, shared))
}

async fn list(
    State(shared): State<Arc<Shared>>,
    headers: HeaderMap,
    Query(query): Query<TokenQuery>,
) -> Response {
    if !request_token(&headers, &query).is_some_and(|t| shared.authorised(&t)) {
        return refuse(StatusCode::UNAUTHORIZED, "a valid token is required");
    }
    let sessions = shared.sessions.lock().expect("sessions lock");
    let list: Vec<_> = sessions
        .iter()
        .map(|(name, e)| {
            let p = e.progress.lock().expect("progress lock").clone();
            let (shown, ended) = e.view.with_shown(|s| {
                (
                    s.triangles,
                    s.ended.as_ref().and_then(|v| v["triangles"].as_u64()),
                )
            });
            json!({
                "name": name,
                "map": e.map,
                "live": e.inbox.is_some() || e.external,
                "frames": p.frames,
                "elements": p.elements,
                // The mesh's triangles once the session ended; while it maps,
                // those its viewers were last sent (null until one watched).
                "triangles": ended.or((shown > 0).then_some(shown as u64)),
            })
        })
        .collect();
    Json(json!({ "sessions": list })).into_response()
}

/// Options of a mesh download: those of `depthmesh export`.
#[derive(Debug, Default, Deserialize)]
struct DownloadQuery {
    token: Option<String>,
    simplify: Option<f32>,
    scale: Option<f32>,
    up: Option<String>,
    align_floor: Option<bool>,
    collision: Option<bool>,
}

async fn download(
    State(shared): State<Arc<Shared>>,
    UrlPath((name, file)): UrlPath<(String, String)>,
    headers: HeaderMap,
    Query(q): Query<DownloadQuery>,
) -> Response {
    let token = TokenQuery {
        token: q.token.clone(),
    };
    if !request_token(&headers, &token).is_some_and(|t| shared.authorised(&t)) {
        return refuse(StatusCode::UNAUTHORIZED, "a valid token is required");
    }
    let format = match file.as_str() {
        "mesh.ply" => Format::Ply,
        "mesh.glb" => Format::Glb,
        _ => return refuse(StatusCode::NOT_FOUND, "download mesh.ply or mesh.glb"),
    };
    let inbox = {
        let sessions = shared.sessions.lock().expect("sessions lock");
        match sessions.get(&name) {
            Some(e) if e.external => {
                return refuse(
                    StatusCode::NOT_FOUND,
                    "a view of a map made elsewhere is not downloaded here: `depthmesh cluster fetch` assembles a site's map",
                )
            }
            Some(e) => e.inbox.clone(),
            None => return refuse(StatusCode::NOT_FOUND, "no such session"),
        }
    };
    let mesh = match inbox {
        Some(inbox) => {
            let (tx, rx) = oneshot::channel();
            inbox.push(crate::worker::Job::Mesh(tx), false);
            match rx.await {
                Ok(mesh) => mesh,
                Err(_) => return refuse(StatusCode::GONE, "the session ended meanwhile: retry"),
            }
        }
        // The name was checked when the session was made, so the path
        // stays inside --out.
        None => {
            let path = shared.options.out.join(&name).join("mesh.ply");
            match tokio::task::spawn_blocking(move || read_mesh(&path)).await {
                Ok(Ok(mesh)) => mesh,
                _ => return refuse(StatusCode::NOT_FOUND, "the session wrote no mesh"),
            }
        }
    };
    let built = tokio::task::spawn_blocking(move || encode_mesh(&mesh, format, &q)).await;
    match built {
        Ok(Ok(bytes)) => {
            let kind = match format {
                Format::Glb => "model/gltf-binary",
                _ => "application/octet-stream",
            };
            ([(header::CONTENT_TYPE, kind)], bytes).into_response()
        }
        Ok(Err(message)) => refuse(StatusCode::BAD_REQUEST, &message),
        Err(_) => refuse(StatusCode::INTERNAL_SERVER_ERROR, "export failed"),
    }
}

/// The mesh as a downloadable file: binary PLY as it is, or GLB through the
/// export pipeline with the query's options.
fn encode_mesh(mesh: &Mesh, format: Format, q: &DownloadQuery) -> Result<Vec<u8>, String> {
    if format == Format::Ply {
        let mut bytes = Vec::new();
        write_ply_to(&mut bytes, mesh, PlyFormat::BinaryLittleEndian).map_err(|e| e.to_string())?;
        return Ok(bytes);
    }
    if let Some(r) = q.simplify {
        if !(r > 0.0 && r <= 1.0) {
            return Err(format!("simplify must be in (0, 1], got {r}"));
        }
    }
    let options = ExportOptions {
        format,
        simplify: q.simplify.map(SimplifyParams::ratio),
        scale: q.scale.unwrap_or(1.0),
        up: match q.up.as_deref() {
            None | Some("y") => UpAxis::Y,
            Some("z") => UpAxis::Z,
            Some(other) => return Err(format!("up must be y or z, got {other}")),
        },
        align_floor: q.align_floor.unwrap_or(false),
        collision: q.collision.unwrap_or(false),
        ..ExportOptions::default()
    };
    let (assets, _) = build_assets(mesh, &options).map_err(|e| e.to_string())?;
    glb_of_assets(&assets).map_err(|e| e.to_string())
}
