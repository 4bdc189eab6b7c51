//! The session thread's side of the view: what to publish, and when.
//!
//! Nothing is done until a viewer first connects. From then on, every
//! [`TICK`] (every [`BUSY_TICK`] while frames wait to be mapped, so that
//! viewers slow the view rather than the mapping), the parts the session
//! changed are meshed and published. The rule for each part:
//!
//! - its first version goes out once the part has existed for
//!   [`FIRST_DELAY`] (surface at the edge of the view grows over a few
//!   frames; one version of it costs less than several);
//! - a later version goes out before the session ends only when its
//!   triangle count changed by [`GROWTH`] of it (surface visibly added or
//!   lost), and not sooner than [`FIRST_WAIT`] after the last version,
//!   that wait doubling each time up to [`LAST_WAIT`]; smaller changes wait
//!   for the end. A surface seen again mostly refines by a fraction of a
//!   voxel, which a viewer cannot see but would pay for in bytes;
//! - when the session ends, every part whose triangles differ from the
//!   version sent, or whose vertices moved more than [`TOLERANCE`], goes
//!   out: viewers end with the session's triangles exactly, each vertex
//!   within [`TOLERANCE`] of the session's mesh (downloads are the mesh
//!   itself).
//!
//! Measured on the kitchen (`bench/view_kitchen.sh`), this sends a viewer
//! 1.2–1.6 times the bytes of the final mesh as a meshopt-compressed GLB.

use super::hub::{ImageKind, Part, TrailPoint, Update, ViewHub};
use crate::jpeg::{self, ColorType};
use depthmesh::mesh::Mesh;
use depthmesh::session::status::StatusImage;
use depthmesh::session::view::PartKey;
use depthmesh::session::Session;
use depthmesh::track::pyramid::half;
use depthmesh::{DepthImage, Intrinsics, Pose};
use serde_json::{json, Map, Value};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Shortest time between two publications: five a second look live.
pub const TICK: Duration = Duration::from_millis(200);
/// Shortest time between two publications while frames wait to be mapped:
/// the view then updates less often rather than slow the mapping down.
pub const BUSY_TICK: Duration = Duration::from_millis(1000);
/// A part is first sent once it has existed this long: at the edge of the
/// view new surface grows over several frames, and one version of it
/// costs less than several (the map on the page lags the sensor by this
/// much; the status image does not).
pub const FIRST_DELAY: Duration = Duration::from_millis(1000);
/// A part's triangle count must change by this share of it for a new
/// version to go out before the session ends.
pub const GROWTH: f32 = 0.2;
/// Wait before a part's second version is sent.
pub const FIRST_WAIT: Duration = Duration::from_millis(2000);
/// Longest wait between versions of a part.
pub const LAST_WAIT: Duration = Duration::from_secs(8);

/// Depths mapped to the ends of the depth image's colours, metres.
const DEPTH_COLOURS: (f32, f32) = (0.3, 4.0);

/// Shortest time between two images: ray casting the status image is the
/// dearest part of a publication.
pub const IMAGE_TICK: Duration = Duration::from_millis(1000);

/// How far a part's vertices may have moved, metres, before its new
/// version is worth sending when its triangles are the same: a surface seen
/// again refines by fractions of a millimetre, which no viewer can see.
/// New, lost or re-connected triangles are always sent.
pub const TOLERANCE: f32 = 0.002;

/// When each part was last sent, how often, and which version.
#[derive(Clone, Debug)]
struct Sent {
    at: Instant,
    times: u32,
    part: Arc<Part>,
}

/// What the session's thread keeps to feed its viewers.
pub struct Feed {
    hub: Arc<ViewHub>,
    following: bool,
    last: Option<Instant>,
    last_images: Option<Instant>,
    sent: HashMap<PartKey, Sent>,
    /// Changed parts whose new version waits its turn, since when.
    waiting: BTreeMap<PartKey, Instant>,
    /// Parts whose latest change was too small to send before the end.
    stale: BTreeSet<PartKey>,
    /// Frames whose trajectory points were published.
    trail_sent: usize,
    /// Frames and bytes received at the last publication, for rates.
    frames_then: usize,
    bytes_then: u64,
    status_k: Intrinsics,
    status: StatusImage,
    rgb: Vec<u8>,
    jpeg: Vec<u8>,
}

impl Feed {
    /// A feed into `hub` for a session whose camera is `k`.
    pub fn new(hub: Arc<ViewHub>, k: &Intrinsics) -> Self {
        Feed {
            hub,
            following: false,
            last: None,
            last_images: None,
            sent: HashMap::new(),
            waiting: BTreeMap::new(),
            stale: BTreeSet::new(),
            trail_sent: 0,
            frames_then: 0,
            bytes_then: 0,
            status_k: quarter(k),
            status: StatusImage::default(),
            rgb: Vec::new(),
            jpeg: Vec::new(),
        }
    }

    /// After a frame (or when a viewer joined): publishes if viewers are
    /// watching and a tick has passed ([`BUSY_TICK`] when `busy`: frames
    /// are waiting). `depth` is the latest frame's depth; `bytes_in` what
    /// the sensor sent so far.
    pub fn after_frame(
        &mut self,
        session: &mut Session,
        depth: &DepthImage,
        bytes_in: u64,
        busy: bool,
    ) {
        if !self.hub.watched() {
            return;
        }
        let now = Instant::now();
        let tick = if busy { BUSY_TICK } else { TICK };
        if self.last.is_some_and(|t| now - t < tick) {
            return;
        }
        let parts = self.changed_parts(session, now, false);
        let mut update = Update {
            parts,
            trail: self.trail(session),
            figures: Some(self.figures(session, now, bytes_in)),
            ..Update::default()
        };
        // Images cost a ray cast: only for someone looking, and less often.
        let images_due = self.last_images.is_none_or(|t| now - t >= IMAGE_TICK);
        if images_due && self.hub.viewers() > 0 {
            if let Some(r) = session.records().last() {
                update.images = self.images(session, &r.estimate.clone(), depth);
                self.last_images = Some(now);
            }
        }
        self.hub.publish(update);
        self.last = Some(now);
    }

    /// After the map changed other than by a frame (a map followed from
    /// elsewhere): publishes changed parts with `figures` if viewers are
    /// watching and a tick has passed, or at once and every changed part
    /// when `settled`.
    pub fn after_change(&mut self, session: &mut Session, figures: Value, settled: bool) {
        if !self.hub.watched() {
            return;
        }
        let now = Instant::now();
        if !settled && self.last.is_some_and(|t| now - t < TICK) {
            return;
        }
        let parts = self.changed_parts(session, now, settled);
        self.hub.publish(Update {
            parts,
            figures: Some(figures),
            ..Update::default()
        });
        self.last = Some(now);
    }

    /// When the session ended: publishes every part not yet sent in its
    /// final version (all of them, if nobody watched: a viewer may still
    /// open the finished session), and the summary.
    pub fn finish(&mut self, session: &mut Session, summary: &Map<String, Value>) {
        session.mesh();
        let now = Instant::now();
        let parts = self.changed_parts(session, now, true);
        let triangles = session.mesh().triangle_count();
        let mut ended = summary.clone();
        ended.insert("triangles".into(), json!(triangles));
        let update = Update {
            parts,
            trail: self.trail(session),
            figures: Some(self.figures(session, now, self.bytes_then)),
            ended: Some(Value::Object(ended)),
            ..Update::default()
        };
        self.hub.publish(update);
    }

    /// The parts to publish now; with `all`, every changed one.
    fn changed_parts(&mut self, session: &mut Session, now: Instant, all: bool) -> Vec<Arc<Part>> {
        let changed = if self.following {
            session.changed_parts()
        } else {
            self.following = true;
            session.follow_parts()
        };
        for k in changed {
            self.stale.remove(&k);
            self.waiting.entry(k).or_insert(now);
        }
        if all {
            let stale = std::mem::take(&mut self.stale);
            self.waiting.extend(stale.into_iter().map(|k| (k, now)));
        }
        let due: Vec<PartKey> = self
            .waiting
            .iter()
            .filter(|(k, since)| {
                all || match self.sent.get(*k) {
                    None => now - **since >= FIRST_DELAY,
                    Some(s) => now - s.at >= wait(s.times),
                }
            })
            .map(|(k, _)| *k)
            .collect();
        for k in &due {
            self.waiting.remove(k);
        }
        let mut parts = Vec::with_capacity(due.len());
        for (k, mesh) in due.iter().zip(session.part_meshes(&due)) {
            // Not held (evicted): the viewer keeps what it has.
            let Some(mesh) = mesh else { continue };
            let times = match self.sent.get(k) {
                // A part that never had triangles is not news.
                None if mesh.triangles.is_empty() => continue,
                Some(s) if same_within(&s.part.mesh, &mesh, TOLERANCE) => continue,
                Some(s) if !all && !grew(&s.part.mesh, &mesh) => {
                    self.stale.insert(*k);
                    continue;
                }
                Some(s) => s.times + 1,
                None => 1,
            };
            let part = Part::new(*k, mesh);
            self.sent.insert(
                *k,
                Sent {
                    at: now,
                    times,
                    part: part.clone(),
                },
            );
            parts.push(part);
        }
        parts
    }

    /// Trajectory points of the frames since the last publication.
    fn trail(&mut self, session: &Session) -> Vec<TrailPoint> {
        let records = &session.records()[self.trail_sent..];
        self.trail_sent = session.records().len();
        records
            .iter()
            .map(|r| {
                let t = r.estimate.translation;
                [t.x, t.y, t.z, if r.fused() { 0.0 } else { 1.0 }]
            })
            .collect()
    }

    /// The live figures (the hub adds the triangles shown).
    fn figures(&mut self, session: &Session, now: Instant, bytes_in: u64) -> Value {
        let records = session.records();
        let seconds = self.last.map_or(0.0, |t| (now - t).as_secs_f64());
        let rate = |count: f64| if seconds > 0.0 { count / seconds } else { 0.0 };
        let fps = rate((records.len() - self.frames_then) as f64);
        let upload = rate(bytes_in.saturating_sub(self.bytes_then) as f64);
        self.frames_then = records.len();
        self.bytes_then = bytes_in;
        let last = records.last();
        let state = match last.and_then(|r| r.track.as_ref()) {
            None => "given poses",
            Some(t) if t.held => "held (something new in view)",
            Some(t) if t.lost.is_some() => "lost",
            Some(t) if t.relocalised => "relocalised",
            Some(t) if t.recovered => "found again",
            Some(t) if t.weak_directions > 0 => "tracking (weak view)",
            Some(_) => "tracking",
        };
        json!({
            "frames": records.len(),
            "fused": session.frames_fused(),
            "lost_frames": records.len() - session.frames_fused(),
            "weak_frames": session.weak_frames(),
            "fps": fps,
            "upload_bytes_per_second": upload,
            "bytes_in": bytes_in,
            "tracking": state,
            "pose": last.map(|r| pose_matrix(&r.estimate)),
        })
    }

    /// The status image from `pose` and the colour-mapped depth image, as JPEGs.
    fn images(
        &mut self,
        session: &Session,
        pose: &Pose,
        depth: &DepthImage,
    ) -> [Option<Arc<Vec<u8>>>; 2] {
        let mut images: [Option<Arc<Vec<u8>>>; 2] = [None, None];
        self.status.draw(session.backend(), &self.status_k, pose);
        let s = &self.status;
        images[ImageKind::Status as usize] = jpeg::encode(
            &s.pixels,
            s.width,
            s.height,
            ColorType::Luma,
            &mut self.jpeg,
        )
        .map(|j| Arc::new(super::wire::encode_image(ImageKind::Status as u32, j)));
        // The depth image at the status image's size, every n-th pixel.
        let n = (depth.width / self.status_k.width.max(1)).max(1) as usize;
        if depth.width as usize >= n && depth.height as usize >= n {
            let (w, h) = (depth.width / n as u32, depth.height / n as u32);
            self.rgb.clear();
            let (near, far) = DEPTH_COLOURS;
            for y in 0..h as usize {
                for x in 0..w as usize {
                    let d = depth.data[n * y * depth.width as usize + n * x];
                    let c = if d > 0.0 && d.is_finite() {
                        depthmesh::palette::turbo((d - near) / (far - near))
                    } else {
                        [0; 3]
                    };
                    self.rgb.extend_from_slice(&c);
                }
            }
            images[ImageKind::Depth as usize] =
                jpeg::encode(&self.rgb, w, h, ColorType::Rgb, &mut self.jpeg)
                    .map(|j| Arc::new(super::wire::encode_image(ImageKind::Depth as u32, j)));
        }
        images
    }
}

/// Whether a part's triangle count changed enough since the version sent
/// to be worth sending before the session ends: by [`GROWTH`] of it.
fn grew(old: &Mesh, new: &Mesh) -> bool {
    let (a, b) = (old.triangle_count() as f32, new.triangle_count() as f32);
    (a - b).abs() >= GROWTH * a.max(1.0)
}

/// Whether `new` has the triangles of `old` (the same vertices, joined
/// the same way) with no vertex moved farther than `tolerance`.
fn same_within(old: &Mesh, new: &Mesh, tolerance: f32) -> bool {
    old.triangles == new.triangles
        && old.positions.len() == new.positions.len()
        && old
            .positions
            .iter()
            .zip(&new.positions)
            .all(|(a, b)| (*a - *b).abs().max_element() <= tolerance)
}

/// The camera the view's status image is drawn for: a quarter of the
/// sensor's resolution (at most halved twice, keeping 80 pixels), as the
/// page shows it small; ray casting it costs a sixteenth of a full one.
fn quarter(k: &Intrinsics) -> Intrinsics {
    let mut q = *k;
    for _ in 0..2 {
        if q.width >= 160 {
            q = half(&q);
        }
    }
    q
}

/// How long a part sent `times` times waits before its next version.
fn wait(times: u32) -> Duration {
    FIRST_WAIT
        .saturating_mul(1 << times.saturating_sub(1).min(16))
        .min(LAST_WAIT)
}

/// A pose as a column-major 4×4 matrix (three.js's `Matrix4.fromArray`).
fn pose_matrix(p: &Pose) -> [f32; 16] {
    let r = p.rotation.to_cols_array();
    let t = p.translation;
    [
        r[0], r[1], r[2], 0.0, r[3], r[4], r[5], 0.0, r[6], r[7], r[8], 0.0, t.x, t.y, t.z, 1.0,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_part_waits_longer_each_time_it_is_sent_up_to_the_limit() {
        assert_eq!(wait(1), FIRST_WAIT);
        assert_eq!(wait(2), 2 * FIRST_WAIT);
        assert_eq!(wait(3), 4 * FIRST_WAIT);
        assert_eq!(wait(40), LAST_WAIT);
    }

    fn strip(n: u32, lift: f32) -> Mesh {
        let mut m = Mesh::default();
        for i in 0..n + 2 {
            m.positions.push(glam::Vec3::new(
                i as f32 * 0.01,
                (i % 2) as f32 * 0.01,
                lift,
            ));
        }
        m.triangles = (0..n).map(|i| [i, i + 1, i + 2]).collect();
        m
    }

    #[test]
    fn only_new_triangles_or_visible_moves_make_a_new_version() {
        let sent = strip(100, 0.0);
        // Refined by a fraction of a millimetre: the viewer keeps its version.
        assert!(same_within(&sent, &strip(100, 0.0015), TOLERANCE));
        // Moved visibly, or triangles changed: a new version.
        assert!(!same_within(&sent, &strip(100, 0.003), TOLERANCE));
        assert!(!same_within(&sent, &strip(99, 0.0), TOLERANCE));
        // Before the end, only a change of a fifth of its triangles goes out.
        assert!(!grew(&sent, &strip(85, 0.0)));
        assert!(grew(&sent, &strip(125, 0.0)));
        assert!(grew(&sent, &strip(50, 0.0)));
    }
}
