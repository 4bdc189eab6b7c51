//! A JetStream-enabled `nats-server` on a loopback port of its own choosing,
//! its data in a scratch folder, stopped when dropped (and the folder
//! removed, when the server made it).

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A running `nats-server`.
pub struct NatsServer {
    child: Child,
    /// `nats://127.0.0.1:PORT`.
    pub url: String,
    /// The scratch folder its store and ports file are in.
    dir: std::path::PathBuf,
    /// Whether the folder is the server's own, removed once it stops.
    owns_dir: bool,
}

impl NatsServer {
    /// Starts one with its store under `dir`; panics, saying so, when
    /// `nats-server` is not installed (`.ci/cluster` installs it).
    pub fn start(dir: &Path) -> NatsServer {
        Self::start_on(dir, "-1")
    }

    /// Starts one in a scratch folder of its own for test `name`, removed
    /// when the server is dropped.
    #[allow(dead_code)] // not every test file needs one without a folder
    pub fn in_scratch(name: &str) -> NatsServer {
        let mut server = Self::start(&super::scratch(name));
        server.owns_dir = true;
        server
    }

    /// Starts one on `port` ("-1": any free one).
    fn start_on(dir: &Path, port: &str) -> NatsServer {
        let ports = dir.join("ports");
        let _ = std::fs::remove_dir_all(&ports);
        std::fs::create_dir_all(&ports).unwrap();
        let child = Command::new(binary())
            .args(["-js", "-a", "127.0.0.1", "-p", port, "--http_port", "0"])
            .arg("-sd")
            .arg(dir.join("jetstream"))
            .arg("--ports_file_dir")
            .arg(&ports)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("nats-server runs (Debian's nats-server package; .ci/cluster installs it)");
        let deadline = Instant::now() + Duration::from_secs(20);
        let url = loop {
            let file = std::fs::read_dir(&ports)
                .unwrap()
                .flatten()
                .find(|e| e.path().extension().is_some_and(|x| x == "ports"));
            let found = file
                .and_then(|f| std::fs::read_to_string(f.path()).ok())
                .and_then(|text| serde_json::from_str::<serde_json::Value>(&text).ok())
                .and_then(|v| v["nats"][0].as_str().map(str::to_string));
            if let Some(url) = found {
                break url;
            }
            assert!(
                Instant::now() < deadline,
                "nats-server did not start in 20 s"
            );
            std::thread::sleep(Duration::from_millis(50));
        };
        NatsServer {
            child,
            url,
            dir: dir.to_path_buf(),
            owns_dir: false,
        }
    }

    /// Stops the server (SIGTERM, as a restart does), waits `down`, and
    /// starts it again on the same port with the same store.
    #[allow(dead_code)] // not every test file restarts it
    pub fn restart(&mut self, down: Duration) {
        let port = self.url.rsplit(':').next().unwrap().to_string();
        let status = Command::new("kill")
            .arg(self.child.id().to_string())
            .status()
            .unwrap();
        assert!(status.success());
        self.child.wait().unwrap();
        std::thread::sleep(down);
        let mut again = Self::start_on(&self.dir, &port);
        assert_eq!(again.url, self.url, "nats-server came back elsewhere");
        // The folder passes to the new one with the store in it; the old
        // one's child is reaped already, so dropping it does nothing.
        again.owns_dir = std::mem::take(&mut self.owns_dir);
        drop(std::mem::replace(self, again));
    }
}

/// `nats-server` on the PATH, or where Debian puts it (`/usr/sbin`, which
/// a user's PATH may lack).
fn binary() -> std::path::PathBuf {
    let on_path = std::env::var_os("PATH")
        .map(|p| {
            std::env::split_paths(&p)
                .map(|d| d.join("nats-server"))
                .collect::<Vec<_>>()
        })
        .unwrap_or_default();
    on_path
        .into_iter()
        .chain([
            "/usr/sbin/nats-server".into(),
            "/usr/bin/nats-server".into(),
        ])
        .find(|p| p.is_file())
        .unwrap_or_else(|| "nats-server".into())
}

impl NatsServer {
    /// The server's process id.
    #[allow(dead_code)] // not every test file stops it by a signal
    pub fn pid(&self) -> u32 {
        self.child.id()
    }
}

impl Drop for NatsServer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        if self.owns_dir {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}
