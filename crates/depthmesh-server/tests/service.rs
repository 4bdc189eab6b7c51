//! The service in-process, on loopback: streamed sessions map what an
//! offline session maps, several at once; bad clients are refused with a
//! reason and the others carry on. Every wait is bounded.

use depthmesh::codec::{Codec, RawDepth};
use depthmesh::mesh::ply::{write_ply_to, PlyFormat};
use depthmesh::session::{MapConfig, Session, SessionConfig, TsdfSettings};
use depthmesh::sim::{NoiseModel, PathSpec, Scene, SceneOptions, SimulatedSensor};
use depthmesh::track::TrackerConfig;
use depthmesh::tsdf::TsdfConfig;
use depthmesh::{DepthImage, Frame, Intrinsics, Pose};
use depthmesh_server::protocol::{ClientMessage, FrameMessage, ServerMessage};
use depthmesh_server::{
    stream, FrameSource, Limits, ServeOptions, Server, SourceFrame, StreamOptions,
};
use futures_util::{SinkExt, StreamExt};
use std::path::{Path, PathBuf};
use std::time::Duration;
use tokio_tungstenite::tungstenite::Message;

const TOKEN: &str = "test-token";
const ROOM: &str = include_str!("../../../scenes/room.toml");
/// No test waits longer than this for the server.
const WAIT: Duration = Duration::from_secs(30);

/// A small camera keeps the tests fast.
fn camera() -> Intrinsics {
    Intrinsics::from_vertical_fov(160, 120, 60.0)
}

fn map(_: Intrinsics) -> MapConfig {
    MapConfig::Tsdf(TsdfSettings {
        config: TsdfConfig::new(0.03),
        range: (0.1, 4.0),
        remesh_every: 0,
        active_radius: None,
    })
}

/// `n` frames around the room, depth in millimetres.
fn frames(n: usize) -> Vec<(SourceFrame, RawDepth)> {
    let scene = Scene::parse(ROOM, Path::new("room.toml"), &SceneOptions::default()).unwrap();
    let mut poses = PathSpec::Helix.build(&scene, 300).unwrap();
    poses.truncate(n);
    let mut sensor = SimulatedSensor::new(camera(), 0.8, 4.0, NoiseModel::None, 0).unwrap();
    poses
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let f = sensor.capture(&scene, i as u32 + 1, p);
            let raw = RawDepth::from_metres(&f.depth, 1000.0).unwrap();
            let meta = SourceFrame {
                index: i as u64 + 1,
                timestamp: f.timestamp,
                pose: Some(*p),
            };
            (meta, raw)
        })
        .collect()
}

struct Frames(Vec<(SourceFrame, RawDepth)>, usize);

impl FrameSource for Frames {
    fn intrinsics(&self) -> Intrinsics {
        camera()
    }
    fn len(&self) -> usize {
        self.0.len()
    }
    fn next_frame(&mut self, raw: &mut RawDepth) -> Option<Result<SourceFrame, String>> {
        let (meta, r) = self.0.get(self.1)?;
        self.1 += 1;
        *raw = r.clone();
        Some(Ok(meta.clone()))
    }
}

/// The mesh an offline session makes of the frames, as PLY bytes, and its poses.
fn offline(frames: &[(SourceFrame, RawDepth)], track: bool) -> (Vec<u8>, Vec<Option<Pose>>) {
    let mut session = Session::new(SessionConfig {
        intrinsics: camera(),
        map: map(camera()),
        tracking: track.then(TrackerConfig::default),
    })
    .unwrap();
    for (i, (meta, raw)) in frames.iter().enumerate() {
        let mut depth = DepthImage::default();
        raw.to_metres(&mut depth);
        depth.clamp_range(0.1, 4.0);
        let frame = Frame {
            index: meta.index as usize,
            timestamp: meta.timestamp,
            depth,
            color: None,
            pose: if track && i > 0 { None } else { meta.pose },
        };
        session.push(&frame).unwrap();
    }
    let poses = session.records().iter().map(|r| r.pose).collect();
    let mut ply = Vec::new();
    write_ply_to(&mut ply, session.mesh(), PlyFormat::BinaryLittleEndian).unwrap();
    (ply, poses)
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("depthmesh-serve-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

async fn start(out: &Path, limits: Limits) -> Server {
    Server::start(ServeOptions {
        checkpoint_every: None,
        bind: "127.0.0.1:0".parse().unwrap(),
        token: TOKEN.into(),
        out: out.to_path_buf(),
        limits,
        depth_range: (0.1, 4.0),
        tracker: TrackerConfig::default(),
        map: Box::new(map),
    })
    .await
    .unwrap()
}

fn options(server: &Server, session: &str) -> StreamOptions {
    StreamOptions {
        url: format!("http://{}", server.addr),
        token: TOKEN.into(),
        session: Some(session.into()),
        codec: Codec::default(),
        rate: None,
        realtime: false,
        track: false,
        status_every: 2,
        reply_timeout: WAIT,
        resume: false,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_streamed_session_maps_exactly_what_an_offline_session_maps() {
    let out = scratch("same");
    let server = start(&out, Limits::default()).await;
    let frames = frames(8);
    for track in [false, true] {
        let name = if track { "tracked" } else { "given" };
        let mut o = options(&server, name);
        o.track = track;
        let source = Box::new(Frames(frames.clone(), 0));
        let r = stream(source, &o, true, |_| {}).await.unwrap();
        let (ply, poses) = offline(&frames, track);
        assert!(r.mesh_ply == ply, "{name}: the streamed mesh differs");
        assert_eq!(r.summary["frames_mapped"], 8);
        assert_eq!(r.summary["status_images"], 4);
        assert_eq!(r.status.len(), 4);
        assert!(r
            .status
            .iter()
            .all(|(_, jpeg)| jpeg.starts_with(&[0xFF, 0xD8])));
        // The session's run files are written on the server too.
        let written = std::fs::read(out.join(name).join("mesh.ply")).unwrap();
        assert!(written == ply);
        let trajectory = std::fs::read_to_string(out.join(name).join("trajectory.txt")).unwrap();
        let expected: Vec<(f64, Pose)> = frames
            .iter()
            .zip(&poses)
            .filter_map(|((m, _), p)| p.map(|p| (m.timestamp, p)))
            .collect();
        assert_eq!(trajectory, depthmesh::trajectory::format_tum(&expected));
    }
    server.stop().await.unwrap();
    std::fs::remove_dir_all(out).unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn four_clients_at_once_each_get_every_frame_mapped_while_a_wrong_token_is_refused() {
    let out = scratch("four");
    let server = start(&out, Limits::default()).await;
    let frames = frames(6);
    let mut clients = Vec::new();
    for i in 0..4 {
        let o = options(&server, &format!("client-{i}"));
        let source = Box::new(Frames(frames.clone(), 0));
        clients.push(tokio::spawn(async move {
            stream(source, &o, false, |_| {}).await
        }));
    }
    let mut wrong = options(&server, "intruder");
    wrong.token = "guess".into();
    let refused = stream(Box::new(Frames(frames.clone(), 0)), &wrong, false, |_| {}).await;
    assert!(refused.unwrap_err().contains("wrong token"));
    let (ply, _) = offline(&frames, false);
    for c in clients {
        let r = c.await.unwrap().unwrap();
        assert_eq!(r.summary["frames_mapped"], 6);
        assert_eq!(r.summary["frames_dropped"], 0);
        assert!(r.mesh_ply == ply);
    }
    assert!(!out.join("intruder").exists());
    server.stop().await.unwrap();
    std::fs::remove_dir_all(out).unwrap();
}

/// Watches session `name` on `url` once it exists (a viewer of a name not
/// yet mapping is refused with 404).
async fn watch_when_listed(url: String, name: &str) -> depthmesh_server::watcher::Watched {
    let deadline = tokio::time::Instant::now() + WAIT;
    loop {
        match depthmesh_server::watcher::watch(&url, TOKEN, name, WAIT).await {
            Ok(w) => return w,
            Err(e) if e.contains("404") && tokio::time::Instant::now() < deadline => {
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
            Err(e) => panic!("{e}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn viewers_end_with_the_sessions_triangles_while_a_stalled_one_holds_nothing_up() {
    let out = scratch("viewers");
    let server = start(&out, Limits::default()).await;
    let url = format!("http://{}", server.addr);
    let frames = frames(16);
    // Paced, so that the viewers join while the session maps.
    let mut o = options(&server, "watched");
    o.rate = Some(40.0);
    let source = Box::new(Frames(frames.clone(), 0));
    let streaming = tokio::spawn(async move { stream(source, &o, false, |_| {}).await });
    let watchers: Vec<_> = (0..2)
        .map(|_| tokio::spawn(watch_when_listed(url.clone(), "watched")))
        .collect();
    // A viewer that connects and never reads: the session must not wait for it.
    let stalled = loop {
        let view = format!("ws://{}/ws/view/watched?token={TOKEN}", server.addr);
        match tokio_tungstenite::connect_async(view).await {
            Ok((socket, _)) => break socket,
            Err(_) => tokio::time::sleep(Duration::from_millis(20)).await,
        }
    };
    let r = tokio::time::timeout(WAIT, streaming)
        .await
        .expect("the session finished despite a stalled viewer")
        .unwrap()
        .unwrap();
    assert_eq!(r.summary["frames_mapped"], 16);
    let (ply, _) = offline(&frames, false);
    let mesh = depthmesh::mesh::ply::read_ply_from_bytes(&ply, Path::new("offline.ply")).unwrap();
    for w in watchers {
        let w = w.await.unwrap();
        let ended = w.ended.expect("the viewer heard the session end");
        assert_eq!(ended["triangles"], mesh.triangle_count());
        assert_eq!(w.triangles as usize, mesh.triangle_count());
        assert_eq!(w.figures["frames"], 16);
        assert!(w.part_messages as usize >= w.parts && w.parts > 0);
    }
    // A viewer that joins after the end gets the finished map, once.
    let late = depthmesh_server::watcher::watch(&url, TOKEN, "watched", WAIT)
        .await
        .unwrap();
    assert_eq!(late.triangles as usize, mesh.triangle_count());
    assert_eq!(late.part_messages as usize, late.parts);
    // Without the token, nothing is shown.
    let refused = depthmesh_server::watcher::watch(&url, "guess", "watched", WAIT).await;
    assert!(refused.unwrap_err().contains("401"));
    drop(stalled);
    server.stop().await.unwrap();
    std::fs::remove_dir_all(out).unwrap();
}

type Socket =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn connect(server: &Server) -> Socket {
    let url = format!("ws://{}/ws", server.addr);
    tokio_tungstenite::connect_async(url).await.unwrap().0
}

fn hello(session: &str, k: Intrinsics) -> Message {
    let m = ClientMessage::Hello {
        resume: false,
        token: TOKEN.into(),
        session: Some(session.into()),
        intrinsics: k,
        track: false,
        realtime: false,
        status_every: 0,
    };
    Message::text(serde_json::to_string(&m).unwrap())
}

/// The server's next message, which must be an error; returns its text.
async fn error_of(ws: &mut Socket) -> String {
    loop {
        let m = tokio::time::timeout(WAIT, ws.next()).await.unwrap();
        match m {
            Some(Ok(Message::Text(t))) => match serde_json::from_str(&t).unwrap() {
                ServerMessage::Error { message } => return message,
                ServerMessage::Welcome { .. } | ServerMessage::Verdict(_) => continue,
                other => panic!("expected an error, got {other:?}"),
            },
            other => panic!("expected an error, got {other:?}"),
        }
    }
}

/// A frame message of `raw` with codec `codec`.
fn frame_message(raw: &RawDepth, codec: Codec) -> Message {
    let mut payload = Vec::new();
    codec.encode(raw, &mut payload);
    let mut bytes = Vec::new();
    FrameMessage {
        index: 1,
        timestamp: 1.0,
        pose: Some(Pose::IDENTITY),
        codec,
        payload,
    }
    .encode(&mut bytes);
    Message::binary(bytes)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_bad_input_is_refused_with_a_reason_and_the_server_carries_on() {
    let out = scratch("bad");
    let limits = Limits {
        max_message_bytes: 1 << 20,
        max_frame_pixels: 1 << 16,
        idle_timeout: Duration::from_secs(2),
        ..Limits::default()
    };
    let server = start(&out, limits).await;
    let good = frames(1).remove(0).1;
    let absurd = Intrinsics {
        fx: 1e-30,
        ..camera()
    };
    let large = Intrinsics::from_vertical_fov(640, 480, 60.0);
    let wrong_size = RawDepth::new(80, 60, 1000.0, vec![1000; 80 * 60]).unwrap();
    // (what is sent after the hello, or instead of it; what the error says)
    let cases: Vec<(&str, Vec<Message>, &str)> = vec![
        ("not-json", vec![Message::text("{oops")], "malformed hello"),
        (
            "binary-first",
            vec![Message::binary(vec![1, 2, 3])],
            "JSON hello",
        ),
        ("absurd", vec![hello("absurd", absurd)], "field of view"),
        ("large", vec![hello("large", large)], "limit"),
        ("bad-name", vec![hello("../up", camera())], "session name"),
        (
            "garbage-frame",
            vec![
                hello("garbage", camera()),
                Message::binary(b"DMF1xx".to_vec()),
            ],
            "malformed frame",
        ),
        (
            "truncated-payload",
            vec![hello("truncated", camera()), {
                let Message::Binary(b) = frame_message(&good, Codec::Levels) else {
                    unreachable!()
                };
                Message::binary(b[..b.len() / 2].to_vec())
            }],
            "frame 1",
        ),
        (
            "size-mismatch",
            vec![
                hello("mismatch", camera()),
                frame_message(&wrong_size, Codec::Rvl),
            ],
            "intrinsics say 160×120",
        ),
        (
            "oversized",
            vec![
                hello("oversized", camera()),
                Message::binary(vec![0; 2 << 20]),
            ],
            "",
        ),
        (
            "unknown-message",
            vec![
                hello("unknown", camera()),
                Message::text(r#"{"type":"reboot"}"#),
            ],
            "malformed message",
        ),
        ("idle", vec![hello("idle", camera())], "idle"),
    ];
    for (name, messages, expected) in cases {
        let mut ws = connect(&server).await;
        for m in messages {
            // The server may close before the last message arrives.
            let _ = ws.send(m).await;
        }
        if expected.is_empty() {
            // An oversized message closes the connection outright.
            let end = tokio::time::timeout(WAIT, async {
                while let Some(Ok(m)) = ws.next().await {
                    if m.is_close() {
                        break;
                    }
                }
            })
            .await;
            assert!(end.is_ok(), "{name}: still open");
        } else {
            let e = error_of(&mut ws).await;
            assert!(e.contains(expected), "{name}: {e}");
        }
    }
    // Nothing was written outside the output folder, and the server still maps.
    assert!(!out.parent().unwrap().join("up").exists());
    let o = options(&server, "after");
    let r = stream(Box::new(Frames(frames(3), 0)), &o, false, |_| {})
        .await
        .unwrap();
    assert_eq!(r.summary["frames_mapped"], 3);
    server.stop().await.unwrap();
    std::fs::remove_dir_all(out).unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_beyond_the_limit_are_refused_and_a_live_name_is_not_reused() {
    let out = scratch("limit");
    let limits = Limits {
        max_sessions: 2,
        ..Limits::default()
    };
    let server = start(&out, limits).await;
    let mut first = connect(&server).await;
    first.send(hello("only", camera())).await.unwrap();
    let welcome = tokio::time::timeout(WAIT, first.next()).await.unwrap();
    assert!(matches!(welcome, Some(Ok(Message::Text(_)))));
    let mut same = connect(&server).await;
    same.send(hello("only", camera())).await.unwrap();
    assert!(error_of(&mut same).await.contains("mapping now"));
    let mut second = connect(&server).await;
    second.send(hello("second", camera())).await.unwrap();
    let welcome = tokio::time::timeout(WAIT, second.next()).await.unwrap();
    assert!(matches!(welcome, Some(Ok(Message::Text(_)))));
    let mut third = connect(&server).await;
    third.send(hello("third", camera())).await.unwrap();
    assert!(error_of(&mut third).await.contains("2 sessions at most"));
    server.stop().await.unwrap();
    std::fs::remove_dir_all(out).unwrap();
}
