//! The session thread's side of the view: what to publish, and when.
//!
//! Nothing is done until a viewer first connects; from then on, at most
//! every [`TICK`], the parts the session changed are meshed and published.
//! A part's first version goes out at once (the map visibly grows); later
//! versions of the same part wait [`FIRST_WAIT`], doubling each time up to
//! [`LAST_WAIT`], because a surface seen again mostly refines by a fraction
//! of a voxel, which a viewer cannot see but would pay for in bytes. When the
//! session ends, every part still waiting goes out, so viewers end with the
//! session's mesh exactly.

use super::hub::{ImageKind, Part, TrailPoint, Update, ViewHub};
use crate::jpeg::{self, ColorType};
use depthmesh::session::status::StatusImage;
use depthmesh::session::view::PartKey;
use depthmesh::session::Session;
use depthmesh::track::pyramid::half;
use depthmesh::{DepthImage, Intrinsics, Pose};
use serde_json::{json, Map, Value};
use std::collections::{BTreeSet, HashMap};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Shortest time between two publications: five a second look live.
pub const TICK: Duration = Duration::from_millis(200);
/// Wait before a part's second version is sent.
pub const FIRST_WAIT: Duration = Duration::from_millis(500);
/// Longest wait between versions of a part.
pub const LAST_WAIT: Duration = Duration::from_secs(8);

/// Depths mapped to the ends of the depth image's colours, metres.
const DEPTH_COLOURS: (f32, f32) = (0.3, 4.0);

/// When each part was last sent, and how often.
#[derive(Clone, Copy, Debug)]
struct Sent {
    at: Instant,
    times: u32,
}

/// What the session's thread keeps to feed its viewers.
pub struct Feed {
    hub: Arc<ViewHub>,
    following: bool,
    last: Option<Instant>,
    sent: HashMap<PartKey, Sent>,
    /// Changed parts whose new version waits its turn.
    waiting: BTreeSet<PartKey>,
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
            sent: HashMap::new(),
            waiting: BTreeSet::new(),
            trail_sent: 0,
            frames_then: 0,
            bytes_then: 0,
            status_k: if k.width >= 320 { half(k) } else { *k },
            status: StatusImage::default(),
            rgb: Vec::new(),
            jpeg: Vec::new(),
        }
    }

    /// After a frame (or when a viewer joined): publishes if viewers are
    /// watching and a tick has passed. `depth` is the latest frame's depth;
    /// `bytes_in` what the sensor sent so far.
    pub fn after_frame(&mut self, session: &mut Session, depth: &DepthImage, bytes_in: u64) {
        if !self.hub.watched() {
            return;
        }
        let now = Instant::now();
        if self.last.is_some_and(|t| now - t < TICK) {
            return;
        }
        let parts = self.changed_parts(session, now, false);
        let mut update = Update {
            parts,
            trail: self.trail(session),
            figures: Some(self.figures(session, now, bytes_in)),
            ..Update::default()
        };
        // Images cost a ray cast: only for someone looking.
        if self.hub.viewers() > 0 {
            if let Some(r) = session.records().last() {
                update.images = self.images(session, &r.estimate.clone(), depth);
            }
        }
        self.hub.publish(update);
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
        self.waiting.extend(changed);
        let due: Vec<PartKey> = self
            .waiting
            .iter()
            .copied()
            .filter(|k| all || self.sent.get(k).is_none_or(|s| now - s.at >= wait(s.times)))
            .collect();
        for k in &due {
            self.waiting.remove(k);
            let s = self.sent.entry(*k).or_insert(Sent { at: now, times: 0 });
            *s = Sent {
                at: now,
                times: s.times + 1,
            };
        }
        due.iter()
            .zip(session.part_meshes(&due))
            .filter_map(|(k, mesh)| mesh.map(|m| Part::new(*k, m)))
            .collect()
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
            Some(t) if t.lost.is_some() => "lost",
            Some(t) if t.relocalised => "relocalised",
            Some(t) if t.weak_directions > 0 => "tracking (weak view)",
            Some(_) => "tracking",
        };
        json!({
            "frames": records.len(),
            "fused": session.frames_fused(),
            "lost_frames": records.len() - session.frames_fused(),
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
        if depth.width >= 2 && depth.height >= 2 {
            let (w, h) = (depth.width / 2, depth.height / 2);
            self.rgb.clear();
            let (near, far) = DEPTH_COLOURS;
            for y in 0..h as usize {
                for x in 0..w as usize {
                    let d = depth.data[2 * y * depth.width as usize + 2 * x];
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
}
