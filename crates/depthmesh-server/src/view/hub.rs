//! What a session shows its viewers, and what each viewer has yet to get.

use axum::body::Bytes;
use depthmesh::mesh::Mesh;
use depthmesh::session::view::PartKey;
use serde_json::Value;
use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use tokio::sync::Notify;

/// One version of a part of the map, encoded once for every viewer.
#[derive(Debug)]
pub struct Part {
    /// The part's key.
    pub key: PartKey,
    /// Its triangles now (none: the part is gone).
    pub mesh: Mesh,
    /// The message viewers get, made by the first viewer that sends it
    /// (shared, not copied, by the others).
    encoded: OnceLock<Bytes>,
}

impl Part {
    /// A version of part `key`.
    pub fn new(key: PartKey, mesh: Mesh) -> Arc<Part> {
        Arc::new(Part {
            key,
            mesh,
            encoded: OnceLock::new(),
        })
    }

    /// The part as a viewer message (see [`super::wire`]).
    pub fn message(&self) -> Bytes {
        self.encoded
            .get_or_init(|| super::wire::encode_part(self.key, &self.mesh).into())
            .clone()
    }
}

/// A point of the sensor's trajectory: position, and 1 when the frame was lost.
pub type TrailPoint = [f32; 4];

/// Kinds of images a viewer is shown.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageKind {
    /// The map seen from the sensor's pose (shaded).
    Status = 0,
    /// The latest depth image, colour-mapped.
    Depth = 1,
}

/// What one viewer has yet to be sent.
#[derive(Debug, Default)]
pub struct Pending {
    /// The newest version of each part not yet sent.
    pub parts: HashMap<PartKey, Arc<Part>>,
    /// Trajectory points from this index on.
    pub trail_from: usize,
    /// Whether the figures changed.
    pub figures: bool,
    /// Which images changed.
    pub images: [bool; 2],
    /// Whether the session's end is to be told.
    pub ended: bool,
}

/// A viewer's queue.
#[derive(Debug, Default)]
pub struct Viewer {
    pending: Mutex<Pending>,
    /// Woken when something is pending.
    pub ready: Notify,
}

impl Viewer {
    /// Takes everything pending, leaving nothing.
    pub fn take(&self) -> Pending {
        let mut p = self.pending.lock().expect("viewer lock");
        let trail_from = p.trail_from;
        std::mem::replace(
            &mut *p,
            Pending {
                trail_from,
                ..Pending::default()
            },
        )
    }

    /// Records that trajectory points up to `to` were sent.
    pub fn sent_trail(&self, to: usize) {
        self.pending.lock().expect("viewer lock").trail_from = to;
    }
}

/// What the hub holds for its viewers.
#[derive(Debug, Default)]
pub struct Shown {
    /// The current version of every part with triangles.
    pub parts: HashMap<PartKey, Arc<Part>>,
    /// The sensor's trajectory so far.
    pub trail: Vec<TrailPoint>,
    /// The latest figures (a JSON object).
    pub figures: Value,
    /// The latest images (JPEG), by [`ImageKind`].
    pub images: [Option<Arc<Vec<u8>>>; 2],
    /// The session's summary once it ended.
    pub ended: Option<Value>,
    /// Triangles of all current parts.
    pub triangles: usize,
}

/// A session's view: what it shows and who is watching.
#[derive(Debug)]
pub struct ViewHub {
    /// What the session looks like for a viewer that connects now
    /// (back-end, camera, how parts are grouped).
    pub info: Value,
    shown: Mutex<Shown>,
    viewers: Mutex<Vec<Arc<Viewer>>>,
    /// Viewers ever connected: the session starts following its map at the first.
    joined: AtomicUsize,
}

impl ViewHub {
    /// A hub for a session described by `info`.
    pub fn new(info: Value) -> Self {
        ViewHub {
            info,
            shown: Mutex::new(Shown::default()),
            viewers: Mutex::new(Vec::new()),
            joined: AtomicUsize::new(0),
        }
    }

    /// Whether any viewer ever connected (until then nothing is published).
    pub fn watched(&self) -> bool {
        self.joined.load(Ordering::Relaxed) > 0
    }

    /// Viewers connected now.
    pub fn viewers(&self) -> usize {
        self.viewers.lock().expect("viewers lock").len()
    }

    /// Adds a viewer, to be sent everything shown so far.
    pub fn join(&self) -> Arc<Viewer> {
        let viewer = Arc::new(Viewer::default());
        {
            let shown = self.shown.lock().expect("shown lock");
            let mut p = viewer.pending.lock().expect("viewer lock");
            p.parts = shown.parts.clone();
            p.figures = true;
            p.images = shown.images.clone().map(|i| i.is_some());
            p.ended = shown.ended.is_some();
        }
        viewer.ready.notify_one();
        self.viewers
            .lock()
            .expect("viewers lock")
            .push(viewer.clone());
        self.joined.fetch_add(1, Ordering::Relaxed);
        viewer
    }

    /// Removes a viewer.
    pub fn leave(&self, viewer: &Arc<Viewer>) {
        self.viewers
            .lock()
            .expect("viewers lock")
            .retain(|v| !Arc::ptr_eq(v, viewer));
    }

    /// Reads what is shown.
    pub fn with_shown<T>(&self, f: impl FnOnce(&Shown) -> T) -> T {
        f(&self.shown.lock().expect("shown lock"))
    }

    /// Publishes new versions of parts (an empty mesh deletes), trajectory
    /// points, figures and images, and wakes the viewers.
    pub fn publish(&self, update: Update) {
        let mut shown = self.shown.lock().expect("shown lock");
        for part in &update.parts {
            let before = match part.mesh.triangles.is_empty() {
                true => shown.parts.remove(&part.key),
                false => shown.parts.insert(part.key, part.clone()),
            };
            shown.triangles -= before.map_or(0, |p| p.mesh.triangle_count());
            shown.triangles += part.mesh.triangle_count();
        }
        shown.trail.extend_from_slice(&update.trail);
        if let Some(mut figures) = update.figures {
            if let Value::Object(f) = &mut figures {
                f.insert("triangles".into(), shown.triangles.into());
                f.insert("parts".into(), shown.parts.len().into());
                f.insert("viewers".into(), self.viewers().into());
            }
            shown.figures = figures;
        }
        for (slot, image) in shown.images.iter_mut().zip(&update.images) {
            if image.is_some() {
                slot.clone_from(image);
            }
        }
        if update.ended.is_some() {
            shown.ended = update.ended;
        }
        let ended = shown.ended.is_some();
        drop(shown);
        for viewer in self.viewers.lock().expect("viewers lock").iter() {
            let mut p = viewer.pending.lock().expect("viewer lock");
            for part in &update.parts {
                p.parts.insert(part.key, part.clone());
            }
            p.figures = true;
            for (flag, image) in p.images.iter_mut().zip(&update.images) {
                *flag |= image.is_some();
            }
            p.ended |= ended;
            drop(p);
            viewer.ready.notify_one();
        }
    }
}

/// One publication of a session's view.
#[derive(Debug, Default)]
pub struct Update {
    /// New versions of parts.
    pub parts: Vec<Arc<Part>>,
    /// Trajectory points since the last update.
    pub trail: Vec<TrailPoint>,
    /// The figures now.
    pub figures: Option<Value>,
    /// New images, by [`ImageKind`].
    pub images: [Option<Arc<Vec<u8>>>; 2],
    /// The session's summary, when it ended.
    pub ended: Option<Value>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn part(key: i32, triangles: usize) -> Arc<Part> {
        let mut mesh = Mesh::default();
        for t in 0..triangles as u32 {
            mesh.positions.extend([glam::Vec3::ZERO; 3]);
            mesh.triangles.push([3 * t, 3 * t + 1, 3 * t + 2]);
        }
        Part::new([key, 0, 0], mesh)
    }

    #[test]
    fn a_viewer_keeps_only_the_newest_version_of_each_part() {
        let hub = ViewHub::new(Value::Null);
        let viewer = hub.join();
        for n in 1..=5 {
            hub.publish(Update {
                parts: vec![part(1, n), part(2, 1)],
                ..Update::default()
            });
        }
        let pending = viewer.take();
        assert_eq!(pending.parts.len(), 2);
        assert_eq!(pending.parts[&[1, 0, 0]].mesh.triangle_count(), 5);
        assert_eq!(hub.with_shown(|s| s.triangles), 6);
        // Deleting a part takes its triangles from the count.
        hub.publish(Update {
            parts: vec![part(2, 0)],
            ..Update::default()
        });
        assert_eq!(hub.with_shown(|s| s.triangles), 5);
        assert!(viewer.take().parts[&[2, 0, 0]].mesh.triangles.is_empty());
    }

    #[test]
    fn a_late_viewer_gets_the_current_map_first() {
        let hub = ViewHub::new(Value::Null);
        hub.publish(Update {
            parts: vec![part(1, 2), part(2, 3), part(2, 0)],
            ..Update::default()
        });
        let late = hub.join();
        let pending = late.take();
        assert_eq!(pending.parts.len(), 1, "a deleted part is not sent");
        assert!(pending.figures);
        assert_eq!(hub.viewers(), 1);
        hub.leave(&late);
        assert_eq!(hub.viewers(), 0);
    }
}
