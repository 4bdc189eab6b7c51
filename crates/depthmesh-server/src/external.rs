//! Views of maps made elsewhere: a cluster site's map, assembled from its
//! shards' checkpoints by whoever follows it, shown like a session's.

use crate::connection::view_info;
use crate::server::{Entry, Server};
use crate::view::feed::Feed;
use crate::view::hub::ViewHub;
use crate::worker::Progress;
use depthmesh::session::Session;
use serde_json::Value;
use std::sync::{Arc, Mutex};

/// A view the server shows of a map kept by its caller: the caller changes
/// the map in a [`Session`] of its own (not fed frames) and says when.
pub struct ExternalView {
    feed: Feed,
    hub: Arc<ViewHub>,
    progress: Arc<Mutex<Progress>>,
}

impl Server {
    /// Lists a view named `name` (a session name) of the map `session`
    /// holds; browsers open it at `/view/NAME`. A session's name is refused.
    pub fn add_view(&self, name: &str, session: &Session) -> Result<ExternalView, String> {
        if !crate::protocol::valid_session_name(name) {
            return Err(format!("{name:?}: 1 to 64 letters, digits, '-' or '_'"));
        }
        let hub = Arc::new(ViewHub::new(view_info(name, session)));
        let progress = Arc::new(Mutex::new(Progress::default()));
        let mut sessions = self.shared.sessions.lock().expect("sessions lock");
        // An earlier view of the same map (followed again after a failure) is replaced.
        if sessions.get(name).is_some_and(|e| !e.external) {
            return Err(format!("a session is named {name} already"));
        }
        sessions.insert(
            name.to_string(),
            Entry {
                map: session.backend().mapper().name(),
                progress: progress.clone(),
                inbox: None,
                external: true,
                view: hub.clone(),
            },
        );
        Ok(ExternalView {
            feed: Feed::new(hub.clone(), &session.config().intrinsics),
            hub,
            progress,
        })
    }
}

impl ExternalView {
    /// Viewers watching now (one who joins wants the map at once).
    pub fn viewers(&self) -> usize {
        self.hub.viewers()
    }

    /// Sends viewers the parts of `session`'s map that changed, and the
    /// page's `figures` (`frames`, `lost_frames`, `weak_frames`, `fps`,
    /// `tracking`, as a session's). With `settled` (nothing is changing
    /// any more), every changed part is sent at once, small changes too,
    /// so viewers hold the map exactly.
    pub fn publish(&mut self, session: &mut Session, figures: Value, settled: bool) {
        {
            let mut p = self.progress.lock().expect("progress lock");
            p.frames = figures["frames"].as_u64().unwrap_or(0);
            p.elements = session.backend().mapper().stats().elements as u64;
        }
        self.feed.after_change(session, figures, settled);
    }
}
