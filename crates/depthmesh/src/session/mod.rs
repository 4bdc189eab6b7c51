//! One mapping run, frame by frame: the pipeline every front end drives.
//!
//! A [`Session`] owns the back-end (built by one factory from a
//! [`MapConfig`]), decides where each frame's pose comes from (the frame's
//! own, or ICP tracking against the map), fuses the frame unless tracking
//! lost it, and keeps what happened: a [`FrameRecord`] per frame (pose,
//! tracking verdict, timings, map size), the trajectory, and the counts a
//! summary needs. `simulate`, `reconstruct` and the server all push frames
//! into a session and only present what it returns, the way KISS-ICP's
//! `RegisterFrame` serves both its Python runner and its ROS node.
//!
//! ```text
//! push(frame) ─► pose (given | tracked) ─► Mapper::integrate ─► record, outcome
//! ```

pub mod backend;
mod poses;
pub mod run_files;
pub mod status;
pub mod view;

pub use backend::{Backend, MapConfig, PlanesSettings, TsdfSettings};
pub use poses::{PoseState, TrackEvent, TrackRecord};

use crate::camera::{Intrinsics, Pose};
use crate::error::{Error, Result};
use crate::image::Frame;
use crate::map::{IntegrateReport, Mapper};
use crate::mesh::Mesh;
use crate::sim::SceneModel;
use crate::track::TrackerConfig;
use glam::IVec3;
use poses::PoseSource;
use serde_json::{json, Map, Value};
use std::time::Instant;

/// Everything a session needs before its first frame.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionConfig {
    /// The camera the frames come from.
    pub intrinsics: Intrinsics,
    /// The back-end and its settings.
    pub map: MapConfig,
    /// `Some`: poses are tracked by ICP with these settings (only the first
    /// frame's pose is taken from the data); `None`: every frame brings its pose.
    pub tracking: Option<TrackerConfig>,
}

/// A saved session's state, to continue it ([`Session::resume`]).
#[derive(Debug)]
pub struct Resumed {
    /// A record per frame mapped.
    pub records: Vec<FrameRecord>,
    /// The map.
    pub map: SavedMap,
    /// The tracking state, when poses were tracked.
    pub poses: Option<PoseState>,
}

/// A saved map, by back-end.
#[derive(Debug)]
pub enum SavedMap {
    /// A TSDF volume.
    Tsdf {
        /// Its blocks (with bounded memory, those that were in memory).
        blocks: Vec<crate::tsdf::Block>,
        /// Frames it had fused.
        frames: u32,
        /// The pose and depth of the last fused frame.
        last_view: Option<(Pose, crate::image::DepthImage)>,
    },
    /// Voxel-plane statistics.
    Planes {
        /// The grid's cells in allocation order: key and voxels.
        cells: Vec<crate::planes::grid::SavedCell>,
        /// Frames integrated.
        frames: u32,
        /// The grid's insertions.
        inserts: u32,
    },
    /// A MABDI map.
    Mabdi(crate::mabdi::MabdiState),
}

impl SavedMap {
    /// Frames the map had integrated.
    pub fn frames(&self) -> u32 {
        match self {
            SavedMap::Tsdf { frames, .. } | SavedMap::Planes { frames, .. } => *frames,
            SavedMap::Mabdi(m) => m.iteration,
        }
    }
}

/// What became of one frame: a row of the run's `stats.csv`.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameRecord {
    /// Frame number (the dataset's, or the simulator's iteration).
    pub frame: usize,
    /// The frame's timestamp in seconds.
    pub timestamp: f64,
    /// Milliseconds the session spent on the frame (tracking and mapping).
    pub ms: f64,
    /// The pose the frame was fused with; `None` when tracking lost it. A
    /// session that fuses at the frames' own poses
    /// ([`Session::fuse_given_poses`]) keeps the tracked pose here.
    pub pose: Option<Pose>,
    /// Where the camera is believed to have been: the fused pose, or the
    /// last good pose for a lost frame. Trajectory errors count these, so a
    /// lost frame costs accuracy instead of vanishing from the figure.
    pub estimate: Pose,
    /// What the back-end reported (nothing for a lost frame).
    pub report: IntegrateReport,
    /// Map elements after the frame.
    pub total_elements: usize,
    /// Mesh vertices after the frame, when the kept mesh is current.
    pub total_vertices: Option<usize>,
    /// How the frame was tracked, when poses are tracked.
    pub track: Option<TrackRecord>,
}

impl FrameRecord {
    /// Whether the frame was fused into the map.
    pub fn fused(&self) -> bool {
        self.pose.is_some()
    }
}

/// Which parts of the map a frame changed, for what updates incrementally
/// (re-meshing, viewers, checkpoints).
#[derive(Clone, Debug, PartialEq)]
pub enum Changed {
    /// Nothing: the frame was not fused.
    Nothing,
    /// Keys of the TSDF blocks whose voxels the frame changed (a block's
    /// mesh also reads the lowest layers of its neighbours above).
    Blocks(Vec<IVec3>),
    /// MABDI and the traditional method: triangles appended at the end of
    /// the mesh, after `removed` triangles were taken out of it.
    Triangles {
        /// Triangles appended (the mesh's last ones).
        appended: usize,
        /// Triangles removed before appending.
        removed: usize,
    },
    /// Voxel planes: the whole map is to be read again (the windows a frame
    /// touches are only known at its next re-mesh).
    Everything,
}

/// What [`Session::push`] returns: the frame's record and what changed.
#[derive(Clone, Debug)]
pub struct FrameOutcome<'a> {
    /// The frame's record (also kept by the session).
    pub record: &'a FrameRecord,
    /// A change of tracking state, if this frame made one.
    pub event: Option<TrackEvent>,
    /// The parts of the map the frame changed.
    pub changed: Changed,
}

/// Frames of a session's records by what became of them.
#[derive(Clone, Copy, Debug, Default)]
struct Tally {
    fused: usize,
    /// Fused with a direction tracking left to the motion model.
    weak: usize,
    /// Lost by following and found by the search in the same frame.
    recovered: usize,
    /// Lost for space seen empty, but followed on (not fused).
    held: usize,
}

impl Tally {
    fn add(&mut self, r: &FrameRecord) {
        if r.fused() {
            self.fused += 1;
            if r.track.is_some_and(|t| t.weak_directions > 0) {
                self.weak += 1;
            }
            if r.track.is_some_and(|t| t.recovered) {
                self.recovered += 1;
            }
        } else if r.track.is_some_and(|t| t.held) {
            self.held += 1;
        }
    }
}

/// One mapping run: frames in, a map and its records out.
#[derive(Debug)]
pub struct Session {
    config: SessionConfig,
    backend: Backend,
    poses: PoseSource,
    records: Vec<FrameRecord>,
    /// Counts over `records`, kept as they grow: a live view asks for them
    /// after every frame.
    tally: Tally,
    /// Triangles of an append-only mesh a viewer has been told of (see
    /// [`view`]); `None` while no viewer follows.
    view_seen: Option<usize>,
    /// What tracking aligns frames against instead of the map (see
    /// [`Session::track_against_scene`]).
    scene_model: Option<SceneModel>,
    /// Fuse at the frames' own poses, not the tracked ones (see
    /// [`Session::fuse_given_poses`]).
    fuse_given: bool,
}

impl Session {
    /// A session with an empty map; settings that cannot work are errors
    /// naming the field.
    pub fn new(config: SessionConfig) -> Result<Self> {
        let backend = config.map.build(config.intrinsics)?;
        let poses = PoseSource::new(config.tracking.clone(), config.intrinsics)?;
        Ok(Session {
            config,
            backend,
            poses,
            records: Vec::new(),
            tally: Tally::default(),
            view_seen: None,
            scene_model: None,
            fuse_given: false,
        })
    }

    /// Tracks frames against `model`, the simulated scene itself, instead
    /// of the map built so far (which still fuses them): the tracker's error
    /// without the error the map's rendition of the scene adds.
    pub fn track_against_scene(&mut self, model: SceneModel) {
        self.scene_model = Some(model);
    }

    /// Fuses each frame tracking keeps at the pose the frame brings (a
    /// simulated frame's true pose) instead of the pose tracking found
    /// against the map: the map is then the one the true poses build, and
    /// the tracked poses' error is what the map's rendition of the scene
    /// adds, without the drift that fusing at estimated poses feeds back.
    /// A frame tracking lost is not fused, as in any tracked run, so the
    /// records' counts stay true; they keep the tracked poses. A frame
    /// without a pose is then an error naming it.
    pub fn fuse_given_poses(&mut self) {
        self.fuse_given = true;
    }

    /// A session that continues one saved after its first records: the
    /// map's state (for now the TSDF's blocks after `frames` fused frames,
    /// and its last fused view), the records so far and, when poses are
    /// tracked, the tracking state.
    pub fn resume(config: SessionConfig, saved: Resumed) -> Result<Self> {
        let mut session = Session::new(config)?;
        match (&mut session.backend, saved.map) {
            (
                Backend::Tsdf(t),
                SavedMap::Tsdf {
                    blocks,
                    frames,
                    last_view,
                },
            ) => {
                t.restore(blocks, frames)?;
                if let Some(view) = last_view {
                    t.set_last_view(view);
                }
            }
            (
                Backend::Planes(p),
                SavedMap::Planes {
                    cells,
                    frames,
                    inserts,
                },
            ) => p.restore(cells, frames, inserts)?,
            (Backend::Mabdi(m), SavedMap::Mabdi(state)) => m.restore(state)?,
            _ => {
                return Err(Error::parameter(
                    "map",
                    "the saved map is of another back-end, or one that cannot be continued",
                ))
            }
        }
        match (saved.poses, session.poses.tracking()) {
            (Some(state), true) => session.poses.restore(state)?,
            (None, false) => {}
            // Saved before its first frame: tracking starts afresh.
            (None, true) if saved.records.is_empty() => {}
            _ => {
                return Err(Error::parameter(
                    "tracking",
                    "the saved session and this one differ in tracking",
                ))
            }
        }
        session.records = saved.records;
        for r in &session.records {
            session.tally.add(r);
        }
        Ok(session)
    }

    /// What tracking carries from frame to frame (`None` with given poses).
    pub fn pose_state(&self) -> Option<PoseState> {
        self.poses.state()
    }

    /// The settings the session was made with.
    pub fn config(&self) -> &SessionConfig {
        &self.config
    }

    /// A frame taken at `timestamp` that was received but will not be
    /// pushed (a live server keeping up with its sensor maps the newest
    /// frame and passes over the ones before): when poses are tracked, the
    /// frames' clock learns from it, so the next frame is predicted across
    /// it and counted as passed over, not as dropped by the sensor.
    pub fn pass(&mut self, timestamp: f64) {
        self.poses.pass(timestamp);
    }

    /// Tracks (or takes) the frame's pose and fuses the frame unless
    /// tracking lost it. A frame whose image does not match the camera, or
    /// that has no pose when poses are given, is an error naming the frame;
    /// the map is then unchanged.
    pub fn push(&mut self, frame: &Frame) -> Result<FrameOutcome<'_>> {
        let k = &self.config.intrinsics;
        if (frame.depth.width, frame.depth.height) != (k.width, k.height)
            || frame.depth.data.len() != k.pixel_count()
        {
            return Err(Error::parameter(
                format!("frame {}", frame.index),
                format!(
                    "depth image is {}×{} ({} values) but the camera is {}×{}",
                    frame.depth.width,
                    frame.depth.height,
                    frame.depth.data.len(),
                    k.width,
                    k.height
                ),
            ));
        }
        let given = if self.fuse_given {
            Some(frame.pose.ok_or_else(|| {
                Error::parameter(
                    format!("frame {}", frame.index),
                    "has no pose to fuse it at: the map is fused from the frames' own poses",
                )
            })?)
        } else {
            None
        };
        let start = Instant::now();
        // 1. Where the camera was: given, or aligned against the map.
        let decided = match self.scene_model.as_mut() {
            Some(model) => {
                let decided = self.poses.decide(frame, model)?;
                // Only the iteration: which of a dynamic scene's objects the
                // next frames see.
                model.integrate(frame, &decided.estimate)?;
                decided
            }
            None => self.poses.decide(frame, self.backend.mapper())?,
        };
        // 2. Fuse, unless tracking lost the frame: at the frame's own pose
        // when told to, else at the tracked one.
        let fused_at = decided.pose.map(|tracked| given.unwrap_or(tracked));
        let report = match fused_at {
            Some(pose) => self.backend.mapper_mut().integrate(frame, &pose)?,
            None => IntegrateReport::default(),
        };
        // 3. Record what happened.
        let changed = match fused_at {
            Some(_) => self.backend.changed(&report),
            None => Changed::Nothing,
        };
        let stats = self.backend.mapper().stats();
        self.records.push(FrameRecord {
            frame: frame.index,
            timestamp: frame.timestamp,
            ms: start.elapsed().as_secs_f64() * 1e3,
            pose: decided.pose,
            estimate: decided.estimate,
            report,
            total_elements: stats.elements,
            total_vertices: stats.vertices,
            track: decided.track,
        });
        let record = self.records.last().expect("just pushed");
        self.tally.add(record);
        Ok(FrameOutcome {
            record,
            event: decided.event,
            changed,
        })
    }

    /// The back-end.
    pub fn backend(&self) -> &Backend {
        &self.backend
    }

    /// The back-end, to change (e.g. to take evicted blocks' meshes).
    pub fn backend_mut(&mut self) -> &mut Backend {
        &mut self.backend
    }

    /// The map's current mesh (re-meshing what changed, if needed).
    pub fn mesh(&mut self) -> &Mesh {
        self.backend.mapper_mut().mesh()
    }

    /// A record per frame pushed, in order.
    pub fn records(&self) -> &[FrameRecord] {
        &self.records
    }

    /// The poses frames were fused with, timestamped.
    pub fn trajectory(&self) -> Vec<(f64, Pose)> {
        self.records
            .iter()
            .filter_map(|r| r.pose.map(|p| (r.timestamp, p)))
            .collect()
    }

    /// Every frame's best pose estimate (see [`FrameRecord::estimate`]),
    /// timestamped: what trajectory errors are computed over.
    pub fn estimates(&self) -> Vec<(f64, Pose)> {
        self.records
            .iter()
            .map(|r| (r.timestamp, r.estimate))
            .collect()
    }

    /// Frames fused into the map.
    pub fn frames_fused(&self) -> usize {
        self.tally.fused
    }

    /// Frames fused with a direction tracking left to the motion model.
    pub fn weak_frames(&self) -> usize {
        self.tally.weak
    }

    /// Seconds spent on frames so far.
    pub fn seconds(&self) -> f64 {
        self.records.iter().map(|r| r.ms).sum::<f64>() / 1e3
    }

    /// The run's summary keys that do not depend on the front end:
    /// `frames_fused` and `fused_fraction`; `tracking`, and when tracking
    /// `lost` (times lost), `lost_frames`, `held_frames` (of those, the
    /// frames followed on but not fused for space seen empty: something in
    /// view where earlier frames saw through), `recovered_frames` (frames
    /// following lost and the search found in the same frame, fused),
    /// `weak_frames` (frames fused with
    /// a direction left to the motion model: the view did not pin it down,
    /// so the map there is only as good as the motion's prediction) and
    /// `track_ms` (mean per tracked frame); the back-end's own keys (see
    /// [`Backend::summarise`]); and
    /// for MABDI and the traditional method the element accounting
    /// (`naive_elements`, `elements_vs_naive`, `removed_elements`,
    /// `novel_pixels`).
    pub fn summarise(&mut self) -> Map<String, Value> {
        let mut summary = Map::new();
        let fused = self.frames_fused();
        summary.insert("frames_fused".into(), json!(fused));
        summary.insert(
            "fused_fraction".into(),
            json!(fused as f64 / self.records.len().max(1) as f64),
        );
        summary.insert("tracking".into(), json!(self.poses.tracking()));
        if self.poses.tracking() {
            summary.insert("lost".into(), json!(self.poses.lost));
            summary.insert("lost_frames".into(), json!(self.poses.lost_frames));
            summary.insert("dropped_frames".into(), json!(self.poses.dropped_frames));
            summary.insert("held_frames".into(), json!(self.tally.held));
            summary.insert("recovered_frames".into(), json!(self.tally.recovered));
            summary.insert("weak_frames".into(), json!(self.weak_frames()));
            summary.insert(
                "track_ms".into(),
                json!(self.poses.track_seconds * 1e3 / self.poses.tracked.max(1) as f64),
            );
        }
        self.backend.summarise(&mut summary);
        if matches!(self.backend, Backend::Mabdi(_) | Backend::Naive(_)) {
            self.summarise_addition(&mut summary);
        }
        summary
    }

    /// MABDI's accounting against the traditional method.
    fn summarise_addition(&self, summary: &mut Map<String, Value>) {
        let column =
            |name: &str| -> f64 { self.records.iter().filter_map(|r| r.report.get(name)).sum() };
        let naive = column("naive_elements");
        let elements = self.backend.mapper().stats().elements;
        summary.insert("naive_elements".into(), json!(naive as u64));
        summary.insert(
            "elements_vs_naive".into(),
            json!(if naive > 0.0 {
                elements as f64 / naive
            } else {
                0.0
            }),
        );
        summary.insert(
            "removed_elements".into(),
            json!(self
                .records
                .iter()
                .map(|r| r.report.removed_elements)
                .sum::<usize>()),
        );
        summary.insert("novel_pixels".into(), json!(column("novel_pixels") as u64));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::Mapper;
    use crate::sim::{NoiseModel, PathSpec, Scene, SceneOptions, SimulatedSensor};
    use crate::tsdf::mapper::TsdfMapper;
    use crate::tsdf::TsdfConfig;
    use std::path::Path;

    const TABLE: &str = include_str!("../../../../scenes/table.toml");
    const ROOM: &str = include_str!("../../../../scenes/room.toml");

    fn frames(n: u32) -> (SimulatedSensor, Vec<Frame>) {
        frames_of(TABLE, n, n as usize)
    }

    /// The first `keep` of `n` frames along `scene`'s helix.
    fn frames_of(scene: &str, n: u32, keep: usize) -> (SimulatedSensor, Vec<Frame>) {
        let scene = Scene::parse(scene, Path::new("scene.toml"), &SceneOptions::default()).unwrap();
        let mut poses = PathSpec::Helix.build(&scene, n).unwrap();
        poses.truncate(keep);
        let mut sensor = SimulatedSensor::kinect(NoiseModel::None, 0);
        let frames = poses
            .iter()
            .enumerate()
            .map(|(i, p)| sensor.capture(&scene, i as u32 + 1, p))
            .collect();
        (sensor, frames)
    }

    /// A session mapping the sensor's frames into a 3 cm TSDF.
    fn tsdf_session(sensor: &SimulatedSensor, tracking: Option<TrackerConfig>) -> Session {
        Session::new(SessionConfig {
            intrinsics: sensor.intrinsics,
            map: MapConfig::Tsdf(TsdfSettings {
                config: TsdfConfig::new(0.03),
                range: (sensor.near, sensor.far),
                remesh_every: 0,
                active_radius: None,
            }),
            tracking,
        })
        .unwrap()
    }

    /// The session's TSDF back-end on its own, to fuse frames beside it.
    fn tsdf_alone(sensor: &SimulatedSensor) -> TsdfMapper {
        TsdfMapper::new(
            TsdfConfig::new(0.03),
            sensor.intrinsics,
            sensor.near,
            sensor.far,
        )
        .unwrap()
    }

    #[test]
    fn a_session_with_given_poses_builds_the_map_its_back_end_builds_alone() {
        let (sensor, frames) = frames(6);
        let mut session = tsdf_session(&sensor, None);
        let mut alone = tsdf_alone(&sensor);
        for f in &frames {
            let outcome = session.push(f).unwrap();
            assert_eq!(outcome.record.pose, f.pose);
            let Changed::Blocks(keys) = outcome.changed else {
                panic!("a TSDF frame changes blocks");
            };
            assert!(!keys.is_empty());
            alone.integrate(f, &f.pose.unwrap()).unwrap();
        }
        assert_eq!(session.mesh(), alone.mesh());
        assert_eq!(session.frames_fused(), 6);
        assert_eq!(session.trajectory().len(), 6);
        let s = session.summarise();
        assert_eq!(s["frames_fused"], 6);
        assert_eq!(s["tracking"], false);
        // Keys of other back-ends do not appear with value 0.
        assert!(s.get("naive_elements").is_none());
    }

    #[test]
    fn a_session_fusing_given_poses_builds_their_map_and_records_the_tracked_ones() {
        let (sensor, frames) = frames_of(ROOM, 300, 6);
        let mut session = tsdf_session(&sensor, Some(TrackerConfig::default()));
        session.fuse_given_poses();
        let mut alone = tsdf_alone(&sensor);
        for f in &frames {
            session.push(f).unwrap();
            alone.integrate(f, &f.pose.unwrap()).unwrap();
        }
        assert_eq!(session.mesh(), alone.mesh());
        // Tracked, not copied: the estimates are near the poses, not them.
        let tracked = session.records().iter().zip(&frames).skip(1);
        assert!(tracked.clone().all(|(r, f)| r.track.is_some()
            && r.estimate.translation.distance(f.pose.unwrap().translation) < 0.01));
        assert!(tracked.clone().any(|(r, f)| Some(r.estimate) != f.pose));
        // A frame with no pose to fuse at is refused, naming it.
        let unposed = Frame {
            pose: None,
            ..frames[1].clone()
        };
        let error = session.push(&unposed).unwrap_err().to_string();
        assert!(
            error.contains(&format!("frame {}", frames[1].index)),
            "{error}"
        );
        assert_eq!(session.records().len(), frames.len());
        // A frame tracking loses (every surface at half its distance) is
        // not fused, though it brings a pose.
        let before = session.mesh().clone();
        let mut halved = frames[1].clone();
        halved.depth.data.iter_mut().for_each(|d| *d *= 0.5);
        let outcome = session.push(&halved).unwrap();
        assert!(outcome.record.track.unwrap().lost.is_some());
        assert_eq!(outcome.record.pose, None);
        assert_eq!(session.mesh(), &before);
        assert_eq!(session.frames_fused(), frames.len());
    }

    #[test]
    fn a_tracked_session_follows_the_true_poses() {
        // The first 10 of 300 steps around the room: about 4 cm a frame.
        let (sensor, frames) = frames_of(ROOM, 300, 10);
        let mut session = tsdf_session(&sensor, Some(TrackerConfig::default()));
        for f in &frames {
            // Only the first frame's pose may be used.
            let unposed = Frame {
                pose: (f.index == frames[0].index).then_some(f.pose.unwrap()),
                ..f.clone()
            };
            session.push(&unposed).unwrap();
        }
        for (r, f) in session.records().iter().zip(&frames) {
            let truth = f.pose.unwrap();
            assert!(r.track.is_some() || r.frame == frames[0].index);
            // Within 1 cm on a noise-free helix (KinectFusion's own accuracy
            // is millimetres here; a pose-convention bug is metres off).
            let error = r.estimate.translation.distance(truth.translation);
            assert!(error < 0.01, "frame {}: {error} m", r.frame);
        }
        assert_eq!(session.frames_fused(), frames.len());
    }

    #[test]
    fn frames_that_do_not_fit_the_camera_or_lack_a_pose_are_refused_and_change_nothing() {
        let (sensor, frames) = frames(2);
        let mut session = tsdf_session(&sensor, None);
        let mut small = frames[0].clone();
        small.depth = crate::image::DepthImage::new(320, 240);
        let e = session.push(&small).unwrap_err().to_string();
        assert!(e.contains("frame 1") && e.contains("320×240"), "{e}");
        let unposed = Frame {
            pose: None,
            ..frames[1].clone()
        };
        let e = session.push(&unposed).unwrap_err().to_string();
        assert!(e.contains("frame 2") && e.contains("no pose"), "{e}");
        assert!(session.records().is_empty());
        assert_eq!(session.mesh().triangle_count(), 0);
    }

    #[test]
    fn the_vertex_count_is_never_that_of_a_stale_mesh() {
        let (sensor, frames) = frames(2);
        let mut session = tsdf_session(&sensor, None);
        let first = session.push(&frames[0]).unwrap().record.total_vertices;
        assert_eq!(first, None, "the mesh was not updated after fusing");
        let vertices = session.mesh().vertex_count();
        assert_eq!(session.backend().mapper().stats().vertices, Some(vertices));
        session.push(&frames[1]).unwrap();
        assert_eq!(session.backend().mapper().stats().vertices, None);
    }

    /// The map a viewer holds after following its parts frame by frame:
    /// joined, the parts are the session's mesh, triangle for triangle.
    #[test]
    fn followed_parts_join_to_the_map_for_every_back_end() {
        let (sensor, frames) = frames(8);
        let tsdf = MapConfig::Tsdf(TsdfSettings {
            config: TsdfConfig::new(0.03),
            range: (sensor.near, sensor.far),
            remesh_every: 2,
            active_radius: None,
        });
        let planes = MapConfig::Planes(PlanesSettings {
            config: crate::planes::PlanesConfig::default(),
            remesh_every: 3,
        });
        let mabdi = crate::mabdi::MabdiConfig::thesis(sensor.intrinsics, sensor.near, sensor.far);
        for map in [
            tsdf,
            planes,
            MapConfig::Mabdi(mabdi),
            MapConfig::Naive(mabdi),
        ] {
            let mut session = Session::new(SessionConfig {
                intrinsics: sensor.intrinsics,
                map,
                tracking: None,
            })
            .unwrap();
            let mut held: std::collections::HashMap<view::PartKey, Mesh> = Default::default();
            let mut apply = |session: &Session, keys: Vec<view::PartKey>| {
                for (k, mesh) in keys.iter().zip(session.part_meshes(&keys)) {
                    match mesh {
                        Some(m) if m.triangles.is_empty() => held.remove(k),
                        Some(m) => held.insert(*k, m),
                        None => None,
                    };
                }
            };
            session.push(&frames[0]).unwrap();
            session.push(&frames[1]).unwrap();
            let keys = session.follow_parts();
            apply(&session, keys);
            for f in &frames[2..] {
                session.push(f).unwrap();
                let keys = session.changed_parts();
                apply(&session, keys);
            }
            let corners = |m: &Mesh| -> Vec<[u32; 9]> {
                (0..m.triangle_count())
                    .map(|t| {
                        let c = m.corners(t);
                        std::array::from_fn(|i| c[i / 3][i % 3].to_bits())
                    })
                    .collect()
            };
            // Asking for the mesh re-meshes what is due; a viewer then
            // hears of it too.
            session.mesh();
            let keys = session.changed_parts();
            apply(&session, keys);
            let mut viewed: Vec<[u32; 9]> = held.values().flat_map(corners).collect();
            let mut expected = corners(session.mesh());
            viewed.sort_unstable();
            expected.sort_unstable();
            assert!(!expected.is_empty(), "{}", map.name());
            assert_eq!(viewed.len(), expected.len(), "{}", map.name());
            assert!(
                viewed == expected,
                "{}: the parts differ from the mesh",
                map.name()
            );
        }
    }
}
