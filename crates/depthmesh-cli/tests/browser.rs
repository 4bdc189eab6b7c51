//! The browser view in headless Chromium, checked as a person would: a
//! simulated sequence is streamed to `depthmesh serve` while the page
//! watches it; when the session ends, the page shows exactly the session's
//! triangles and frames, the picture is not blank, the download works, and a
//! wrong token shows an error instead of a view. Needs chromium and
//! chromedriver, so it is ignored by default; `.ci/browser` installs them
//! and runs it.

mod common;

use common::scratch;
use common::served::{Served, TOKEN};
use common::webdriver::Browser;
use serde_json::Value;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const TABLE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/table.toml");
const FRAMES: u32 = 24;

#[test]
#[ignore = "needs chromium and chromedriver: run by .ci/browser"]
fn the_page_shows_every_triangle_of_a_session_for_each_back_end() {
    let dir = scratch("browser-view");
    let browser = Browser::start(&dir, 1024, 700);
    for map in ["tsdf", "mabdi", "planes"] {
        let served = Served::start(&dir.join(map), &["--map", map, "--voxel", "0.02"]);
        let name = format!("view-{map}");
        // Slow enough that the page joins while the session maps.
        let mut stream = Command::new(env!("CARGO_BIN_EXE_depthmesh"))
            .args([
                "stream",
                "--scene",
                TABLE,
                "--iterations",
                &FRAMES.to_string(),
            ])
            .args([
                "--rate",
                "8",
                "--quiet",
                "--server",
                &served.url,
                "--token",
                TOKEN,
            ])
            .args(["--session", &name, "--status-every", "0"])
            .arg("--out")
            .arg(dir.join(format!("stream-{map}")))
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap();
        let deadline = Instant::now() + Duration::from_secs(30);
        while session(&served, &name).is_none() {
            assert!(
                Instant::now() < deadline,
                "{map}: the session never appeared"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        browser.open(&format!("{}/view/{name}#token={TOKEN}", served.url));
        let ended = browser.wait_for(
            "return document.body.dataset.ended || null",
            Duration::from_secs(120),
            "the session's end on the page",
        );
        assert!(stream.wait().unwrap().success(), "{map}: stream failed");
        let listed = session(&served, &name).unwrap();
        assert_eq!(listed["live"], false);
        let triangles = listed["triangles"].as_u64().unwrap();
        let mesh =
            depthmesh::mesh::io::read_mesh(&dir.join(map).join(&name).join("mesh.ply")).unwrap();
        assert_eq!(triangles as usize, mesh.triangle_count(), "{map}");
        assert_eq!(ended, Value::String(triangles.to_string()), "{map}");
        // Parts still being decoded are counted when they are shown.
        let shown = browser.wait_for(
            &format!(
                "const t = document.getElementById('triangles').textContent; \
                 return t === '{triangles}' ? t : null"
            ),
            Duration::from_secs(60),
            &format!("{triangles} triangles on the page ({map})"),
        );
        assert_eq!(shown, Value::String(triangles.to_string()));
        assert_eq!(browser.text("frames"), Value::String(FRAMES.to_string()));
        assert_eq!(browser.text("lost"), Value::String("0".into()));
        // Let a few frames draw what arrived, then look.
        std::thread::sleep(Duration::from_millis(500));
        let png = browser.screenshot();
        std::fs::write(dir.join(format!("{map}.png")), &png).unwrap();
        assert_not_blank(&png, map);
        let href = browser
            .eval("return document.getElementById('download-glb').getAttribute('href')")
            .as_str()
            .unwrap()
            .to_string();
        let (status, glb) = served.get(&href);
        assert_eq!(status, 200, "{map}: download {href}");
        let meshes = depthmesh::mesh::glb::read_glb_from_bytes(&glb).unwrap();
        let downloaded: usize = meshes.iter().map(|m| m.mesh.triangle_count()).sum();
        assert!(downloaded > 0 && downloaded <= triangles as usize, "{map}");
        if map == "tsdf" {
            browser.open(&format!("{}/view/{name}#token=wrong-{TOKEN}", served.url));
            let error = browser.wait_for(
                "const e = document.getElementById('error'); return e.hidden ? null : e.textContent",
                Duration::from_secs(20),
                "the wrong token's error",
            );
            assert!(error.as_str().unwrap().contains("Wrong token"), "{error}");
            assert_eq!(
                browser.eval("return document.getElementById('view').hidden"),
                true
            );
            assert_eq!(browser.text("triangles"), Value::String("0".into()));
        }
    }
    drop(browser);
    std::fs::remove_dir_all(dir).unwrap();
}

/// The listing's entry for session `name`, if it is listed.
fn session(served: &Served, name: &str) -> Option<Value> {
    let (status, body) = served.get(&format!("/api/sessions?token={TOKEN}"));
    assert_eq!(status, 200);
    let list: Value = serde_json::from_slice(&body).unwrap();
    list["sessions"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["name"] == name)
        .cloned()
}

/// Fails unless the screenshot shows something: the map's shading gives
/// many colours, and no one colour covers most of the window.
fn assert_not_blank(png_bytes: &[u8], map: &str) {
    let decoder = png::Decoder::new(std::io::Cursor::new(png_bytes));
    let mut reader = decoder.read_info().unwrap();
    let mut pixels = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut pixels).unwrap();
    let channels = info.color_type.samples();
    let mut counts = std::collections::HashMap::new();
    for p in pixels[..info.buffer_size()].chunks(channels) {
        *counts.entry([p[0], p[1], p[2]]).or_insert(0usize) += 1;
    }
    let total = (info.width * info.height) as usize;
    let most = counts.values().max().copied().unwrap_or(0);
    assert!(
        counts.len() > 200 && most < total * 7 / 10,
        "{map}: the screenshot looks blank ({} colours, the commonest on {} of {total} pixels)",
        counts.len(),
        most
    );
}
