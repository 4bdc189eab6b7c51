//! `depthmesh serve` and `depthmesh stream` as processes, on loopback: a
//! streamed recording gives the mesh `reconstruct` gives, the mesh can be
//! downloaded, and refusals say why. Every server is stopped by its guard.

mod common;

use common::{assert_fails_with, depthmesh, ok, scratch, simulated_frames_folder};
use serde_json::Value;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

const TOKEN: &str = "cli-test-token";

/// A running `depthmesh serve`, killed when dropped.
struct Served {
    child: Child,
    /// `http://127.0.0.1:PORT`.
    url: String,
}

impl Served {
    fn start(out: &Path, extra: &[&str]) -> Served {
        let mut child = Command::new(env!("CARGO_BIN_EXE_depthmesh"))
            .args([
                "serve",
                "--bind",
                "127.0.0.1:0",
                "--token",
                TOKEN,
                "--idle-timeout",
                "20",
            ])
            .args(["--out", out.to_str().unwrap()])
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let url = line
            .trim()
            .strip_prefix("listening on ")
            .unwrap_or_else(|| panic!("first line: {line:?}"))
            .to_string();
        Served { child, url }
    }

    /// `GET path` over plain HTTP/1.1: the status code and the body.
    fn get(&self, path: &str) -> (u16, Vec<u8>) {
        let host = self.url.trim_start_matches("http://");
        let mut s = TcpStream::connect(host).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
        write!(
            s,
            "GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n"
        )
        .unwrap();
        let mut response = Vec::new();
        s.read_to_end(&mut response).unwrap();
        let split = response.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
        let head = String::from_utf8_lossy(&response[..split]).to_string();
        let status = head.split(' ').nth(1).unwrap().parse().unwrap();
        let mut body = response[split + 4..].to_vec();
        if head
            .to_ascii_lowercase()
            .contains("transfer-encoding: chunked")
        {
            body = unchunk(&body);
        }
        (status, body)
    }
}

impl Drop for Served {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The body of a chunked HTTP response.
fn unchunk(mut bytes: &[u8]) -> Vec<u8> {
    let mut body = Vec::new();
    loop {
        let end = bytes.windows(2).position(|w| w == b"\r\n").unwrap();
        let size = usize::from_str_radix(std::str::from_utf8(&bytes[..end]).unwrap(), 16).unwrap();
        if size == 0 {
            return body;
        }
        body.extend_from_slice(&bytes[end + 2..end + 2 + size]);
        bytes = &bytes[end + 4 + size..];
    }
}

fn stream_args<'a>(served: &'a Served, folder: &'a str, out: &'a str) -> Vec<&'a str> {
    vec![
        "stream",
        folder,
        "--server",
        &served.url,
        "--token",
        TOKEN,
        "--rate",
        "max",
        "--quiet",
        "--out",
        out,
    ]
}

#[test]
fn a_folder_streamed_through_serve_gives_the_mesh_reconstruct_gives() {
    let dir = scratch("serve-same");
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    simulated_frames_folder(&frames, 8);
    let served = Served::start(&dir.join("server"), &["--voxel", "0.02"]);
    let offline = dir.join("offline");
    ok(&depthmesh(&[
        "reconstruct",
        frames.to_str().unwrap(),
        "--voxel",
        "0.02",
        "--quiet",
        "--out",
        offline.to_str().unwrap(),
    ]));
    let expected = std::fs::read(offline.join("mesh.ply")).unwrap();
    for codec in ["default", "rvl", "png", "raw"] {
        let out = dir.join(codec);
        let mut args = stream_args(&served, frames.to_str().unwrap(), out.to_str().unwrap());
        args.extend(["--codec", codec, "--session", codec, "--status-every", "4"]);
        args.push("--save-status");
        ok(&depthmesh(&args));
        assert!(
            std::fs::read(out.join("mesh.ply")).unwrap() == expected,
            "{codec}"
        );
        let s: Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(s["frames_sent"], 8);
        assert_eq!(s["frames_mapped"], 8);
        assert_eq!(s["frames_dropped"], 0);
        assert_eq!(s["status_images"], 2);
        assert!(out.join("status/frame-000003.jpg").exists());
        // The server wrote the run's files for the session.
        let server_mesh = dir.join("server").join(codec).join("mesh.ply");
        assert!(std::fs::read(server_mesh).unwrap() == expected);
    }
    let (status, glb) = served.get(&format!(
        "/api/sessions/rvl/mesh.glb?simplify=0.5&token={TOKEN}"
    ));
    assert_eq!(status, 200);
    assert_eq!(&glb[..4], b"glTF");
    let (status, ply) = served.get(&format!("/api/sessions/rvl/mesh.ply?token={TOKEN}"));
    assert_eq!(status, 200);
    assert!(ply == expected);
    let (status, list) = served.get(&format!("/api/sessions?token={TOKEN}"));
    assert_eq!(status, 200);
    let list: Value = serde_json::from_slice(&list).unwrap();
    assert_eq!(list["sessions"].as_array().unwrap().len(), 4);
    assert_eq!(served.get("/api/sessions/rvl/mesh.ply?token=guess").0, 401);
    assert_eq!(
        served.get("/api/sessions/rvl/../../x?token=guess").0 / 100,
        4
    );
    drop(served);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn a_live_sensor_gets_its_newest_frames_mapped_and_the_dropped_ones_counted() {
    let dir = scratch("serve-realtime");
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    simulated_frames_folder(&frames, 12);
    let served = Served::start(&dir.join("server"), &["--voxel", "0.02"]);
    let out = dir.join("out");
    let mut args = stream_args(&served, frames.to_str().unwrap(), out.to_str().unwrap());
    args[7] = "500";
    args.push("--realtime");
    ok(&depthmesh(&args));
    let s: Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let count = |k: &str| s[k].as_u64().unwrap();
    assert_eq!(count("frames_sent"), 12);
    assert_eq!(count("frames_mapped") + count("frames_dropped"), 12);
    assert!(count("frames_mapped") >= 1);
    drop(served);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn refusals_name_their_reason() {
    let dir = scratch("serve-refusals");
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    simulated_frames_folder(&frames, 2);
    let served = Served::start(&dir.join("server"), &[]);
    let out = dir.join("out");
    let mut args = stream_args(&served, frames.to_str().unwrap(), out.to_str().unwrap());
    args[5] = "guess";
    assert_fails_with(&depthmesh(&args), &["wrong token"]);
    let mut args = stream_args(&served, frames.to_str().unwrap(), out.to_str().unwrap());
    args.extend(["--session", "../escape"]);
    assert_fails_with(&depthmesh(&args), &["session name"]);
    assert!(!dir.join("escape").exists());
    drop(served);
    // Listening beyond this machine needs a token; nothing is bound.
    assert_fails_with(
        &depthmesh(&[
            "serve",
            "--bind",
            "0.0.0.0:0",
            "--out",
            dir.to_str().unwrap(),
        ]),
        &["--token"],
    );
    std::fs::remove_dir_all(dir).unwrap();
}
