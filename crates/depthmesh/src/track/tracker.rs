//! Frame-to-model tracking: each frame is aligned by coarse-to-fine ICP
//! against the map's prediction from the last good pose; a failed
//! alignment is reported and never used.

use super::filter::{Bilateral, BilateralParams};
use super::icp::{apply_motion, equations, Association};
use super::pyramid::{half, Pyramid};
use crate::camera::{Intrinsics, Pose};
use crate::error::{Error, Result};
use crate::image::DepthImage;
use crate::map::Mapper;
use std::fmt;

/// Pyramid levels; the coarsest is 1/4 of the full resolution.
pub const LEVELS: usize = 3;

/// Frames a lost camera's last motion is extrapolated over, at most (half a
/// second at 30 Hz); beyond that it says little about where the camera is.
const MAX_EXTRAPOLATED: usize = 15;

/// The model view is not made narrower than this by
/// [`TrackerConfig::model_halvings`]: coarser, its depth edges and missing
/// normals cover too much of the frame.
pub const MIN_MODEL_WIDTH: u32 = 160;

/// Tracking parameters; the defaults are KinectFusion's where it has one,
/// except the iterations: Open3D's (6, 3, 1) track 7-Scenes as accurately
/// as KinectFusion's (10, 5, 4) at a third of the cost.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackerConfig {
    /// ICP iterations per level, coarsest first.
    pub iterations: [usize; LEVELS],
    /// Associations farther apart are outliers (metres).
    pub max_distance: f32,
    /// Associations whose normals differ more are outliers (degrees).
    pub max_normal_angle: f32,
    /// Smoothing of the frame's depth before tracking (`None`: raw depth).
    pub bilateral: Option<BilateralParams>,
    /// Lost when fewer than this fraction of the frame's points are inliers.
    pub min_inlier_fraction: f64,
    /// Lost when the inliers' RMS point-to-plane error is larger (metres).
    pub max_rms: f64,
    /// Lost when the alignment leaves a direction this weakly constrained
    /// (see [`super::icp::Equations::conditioning`]).
    pub min_conditioning: f64,
    /// Lost when the frame moved more than this from the prediction (metres).
    pub max_jump: f32,
    /// Iterations stop once an update moves points less than this (metres).
    pub convergence: f64,
    /// Predict the model view at the frame's resolution halved this many
    /// times: every level of the frame still associates with it, point to
    /// plane, and ray casting is the largest cost of tracking. A frame the
    /// view cannot align is tried again against a view at twice that
    /// resolution (one halving fewer) before it is judged lost: views with
    /// little structure keep more of their edges and normals there. On
    /// 7-Scenes a quarter (2) tracks as accurately as half resolution (the
    /// same frame-to-frame consistency; ATE 5.26 against 5.38 cm) in a third
    /// of the ray-casting time. Never below [`MIN_MODEL_WIDTH`] pixels.
    pub model_halvings: u32,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        TrackerConfig {
            iterations: [6, 3, 1],
            max_distance: 0.1,
            max_normal_angle: 20.0,
            bilateral: Some(BilateralParams::default()),
            min_inlier_fraction: 0.25,
            max_rms: 0.02,
            min_conditioning: 2e-3,
            max_jump: 0.3,
            convergence: 1e-5,
            model_halvings: 2,
        }
    }
}

impl TrackerConfig {
    /// Rejects settings that cannot track.
    pub fn validate(&self) -> Result<()> {
        let positive = [
            ("max_distance", f64::from(self.max_distance)),
            ("max_normal_angle", f64::from(self.max_normal_angle)),
            ("max_rms", self.max_rms),
            ("max_jump", f64::from(self.max_jump)),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::parameter(name, format!("must be positive, got {v}")));
            }
        }
        if self.model_halvings > 4 {
            return Err(Error::parameter(
                "model_halvings",
                format!(
                    "at most 4 (1/16 of the resolution), got {}",
                    self.model_halvings
                ),
            ));
        }
        if self.iterations.iter().all(|&i| i == 0) {
            return Err(Error::parameter(
                "iterations",
                "all levels have 0 iterations",
            ));
        }
        if let Some(b) = &self.bilateral {
            b.validate()?;
        }
        Ok(())
    }
}

/// Why a frame could not be aligned.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LostReason {
    /// The map predicts nothing from the last good pose.
    EmptyModel,
    /// Too few frame points matched the model (fraction of candidates).
    FewInliers(f64),
    /// The matched points disagree with the model (RMS error, metres).
    LargeError(f64),
    /// The geometry does not constrain every direction, e.g. a single plane
    /// (the conditioning figure).
    Degenerate(f64),
    /// The alignment jumped implausibly far from the prediction (metres).
    Jump(f32),
}

impl fmt::Display for LostReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LostReason::EmptyModel => write!(f, "the map predicts no surface from the last pose"),
            LostReason::FewInliers(x) => {
                write!(f, "only {:.0} % of the points match the map", x * 100.0)
            }
            LostReason::LargeError(e) => write!(f, "residual {:.1} mm is too large", e * 1e3),
            LostReason::Degenerate(c) => {
                write!(
                    f,
                    "the view does not constrain all six degrees of freedom (conditioning {c:.1e})"
                )
            }
            LostReason::Jump(d) => {
                write!(f, "the pose jumped {:.0} cm from the prediction", d * 100.0)
            }
        }
    }
}

/// The outcome of tracking one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tracked {
    /// The frame's pose, camera-to-world (the last good pose when lost).
    pub pose: Pose,
    /// `Some` when the frame could not be aligned and must not be fused.
    pub lost: Option<LostReason>,
    /// Fraction of the frame's points matched at the finest level.
    pub inlier_fraction: f64,
    /// RMS point-to-plane error of the matches at the finest level (metres).
    pub rms: f64,
    /// How well the view constrains the pose (see
    /// [`super::icp::Equations::conditioning`]).
    pub conditioning: f64,
    /// ICP iterations run, all levels.
    pub iterations: usize,
}

/// Frame-to-model ICP tracker with a constant-velocity motion model.
#[derive(Debug)]
pub struct Tracker {
    config: TrackerConfig,
    intrinsics: Intrinsics,
    /// The camera model of the model view.
    model_intrinsics: Intrinsics,
    /// The finer model view a frame is tried against when the first cannot
    /// align it (`None` when the model view is already the finest).
    fallback_intrinsics: Option<Intrinsics>,
    filter: Option<Bilateral>,
    filtered: DepthImage,
    frame: Pyramid,
    model: Pyramid,
    last_good: Pose,
    /// Motion between the last two consecutive good frames (camera-to-camera).
    velocity: Pose,
    /// Frames lost since the last good one.
    lost_streak: usize,
}

impl Tracker {
    /// A tracker for frames from `intrinsics`, starting at `start`.
    pub fn new(config: TrackerConfig, intrinsics: Intrinsics, start: Pose) -> Result<Self> {
        config.validate()?;
        intrinsics.validate()?;
        let halved = |times: u32| {
            (0..times).fold(intrinsics, |k, _| {
                if k.width / 2 >= MIN_MODEL_WIDTH {
                    half(&k)
                } else {
                    k
                }
            })
        };
        let model_intrinsics = halved(config.model_halvings);
        let finer = halved(config.model_halvings.saturating_sub(1));
        Ok(Tracker {
            filter: config.bilateral.map(Bilateral::new).transpose()?,
            model_intrinsics,
            fallback_intrinsics: (finer != model_intrinsics).then_some(finer),
            config,
            intrinsics,
            filtered: DepthImage::default(),
            frame: Pyramid::default(),
            model: Pyramid::default(),
            last_good: start,
            velocity: Pose::IDENTITY,
            lost_streak: 0,
        })
    }

    /// The last pose that was tracked successfully (or the start).
    pub fn last_good(&self) -> Pose {
        self.last_good
    }

    /// Aligns `depth` with what `map` predicts from the last good pose.
    pub fn track(&mut self, depth: &DepthImage, map: &dyn Mapper) -> Tracked {
        self.prepare(depth);
        let model = map.render_depth(&self.model_intrinsics, &self.last_good);
        let mut result = self.align(&model, self.model_intrinsics);
        if let (Some(_), Some(k)) = (result.lost, self.fallback_intrinsics) {
            let model = map.render_depth(&k, &self.last_good);
            let first = result.iterations;
            result = self.align(&model, k);
            result.iterations += first;
        }
        self.conclude(result)
    }

    /// The camera model [`Tracker::track_against`] expects the model view in.
    pub fn model_intrinsics(&self) -> Intrinsics {
        self.model_intrinsics
    }

    /// Aligns `depth` with `model`, the map's depth seen from the last good
    /// pose with [`Tracker::model_intrinsics`].
    pub fn track_against(&mut self, depth: &DepthImage, model: &DepthImage) -> Tracked {
        self.prepare(depth);
        let result = self.align(model, self.model_intrinsics);
        self.conclude(result)
    }

    /// Filters `depth` and builds its pyramid.
    fn prepare(&mut self, depth: &DepthImage) {
        let input = match &self.filter {
            Some(f) => {
                f.apply(depth, &mut self.filtered);
                &self.filtered
            }
            None => depth,
        };
        self.frame.build(input, &self.intrinsics, LEVELS);
    }

    /// Aligns the prepared frame with `model` (seen with `model_k` from the
    /// last good pose) and judges the result; the tracker's state is left
    /// as it was. The returned pose is the frame's motion from the last
    /// good pose.
    fn align(&mut self, model: &DepthImage, model_k: Intrinsics) -> Tracked {
        self.model.build(model, &model_k, LEVELS);
        // Nothing to align with: judged once, without running ICP.
        if self.model.levels[0]
            .normals
            .iter()
            .all(|n| *n == glam::Vec3::ZERO)
        {
            return Tracked {
                pose: Pose::IDENTITY,
                lost: Some(LostReason::EmptyModel),
                inlier_fraction: 0.0,
                rms: 0.0,
                conditioning: 0.0,
                iterations: 0,
            };
        }
        if self.lost_streak == 0 {
            return self.icp_from(self.velocity);
        }
        // Recovering: the camera has most likely kept moving as it did
        // before the loss; if not, it is near the last good pose.
        let frames = (self.lost_streak + 1).min(MAX_EXTRAPOLATED);
        let extrapolated = (0..frames).fold(Pose::IDENTITY, |m, _| m.compose(&self.velocity));
        let moving = self.icp_from(extrapolated);
        if moving.lost.is_none() {
            return moving;
        }
        let mut still = self.icp_from(Pose::IDENTITY);
        still.iterations += moving.iterations;
        still
    }

    /// Coarse-to-fine ICP of the prepared frame against the model pyramid,
    /// from the frame motion `predicted`, and the verdict on its result.
    fn icp_from(&self, predicted: Pose) -> Tracked {
        let recovering = self.lost_streak > 0;
        let widen = if recovering { 2.0 } else { 1.0 };
        let assoc = Association {
            max_distance: self.config.max_distance * widen,
            min_normal_cos: self.config.max_normal_angle.to_radians().cos(),
        };
        let mut relative = predicted;
        let mut iterations = 0;
        // The last system solved: the alignment is judged by it (its
        // update, at convergence, is below the noise).
        let mut eq = super::icp::Equations::default();
        for (level, &count) in (0..LEVELS).rev().zip(&self.config.iterations) {
            let extra = if recovering && level == LEVELS - 1 {
                count
            } else {
                0
            };
            for _ in 0..count + extra {
                eq = equations(
                    &self.frame.levels[level],
                    &self.model.levels[level],
                    &relative,
                    &assoc,
                );
                iterations += 1;
                let Some((omega, t)) = eq.solve() else { break };
                relative = apply_motion(&relative, omega, t);
                let rotation = omega.iter().map(|w| w * w).sum::<f64>().sqrt();
                let translation = t.iter().map(|v| v * v).sum::<f64>().sqrt();
                // A rotation moves points by about ω × their range.
                let range = (eq.squared_range / eq.inliers.max(1) as f64).sqrt();
                if translation + rotation * range < self.config.convergence {
                    break;
                }
            }
        }
        let inlier_fraction = eq.inliers as f64 / eq.candidates.max(1) as f64;
        let rms = eq.rms();
        let conditioning = eq.conditioning();
        let jump = (relative.translation - predicted.translation).length();
        let lost = if inlier_fraction < self.config.min_inlier_fraction {
            Some(LostReason::FewInliers(inlier_fraction))
        } else if rms > self.config.max_rms {
            Some(LostReason::LargeError(rms))
        } else if conditioning < self.config.min_conditioning {
            Some(LostReason::Degenerate(conditioning))
        } else if jump > self.config.max_jump * widen {
            Some(LostReason::Jump(jump))
        } else {
            None
        };
        Tracked {
            pose: relative,
            lost,
            inlier_fraction,
            rms,
            conditioning,
            iterations,
        }
    }

    /// Moves the tracker on by an alignment from [`Tracker::align`]: to the
    /// frame's pose when it was aligned, nowhere when it was lost.
    fn conclude(&mut self, result: Tracked) -> Tracked {
        let pose = match result.lost {
            None => {
                let pose = self.last_good.compose(&result.pose);
                // After a loss the motion spans several frames; the last
                // frame-to-frame one is kept.
                if self.lost_streak == 0 {
                    self.velocity = result.pose;
                }
                self.last_good = pose;
                self.lost_streak = 0;
                pose
            }
            Some(_) => {
                self.lost_streak += 1;
                self.last_good
            }
        };
        Tracked { pose, ..result }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{NoiseModel, Scene, SceneOptions, SimulatedSensor};
    use glam::Vec3;
    use std::path::Path;

    const ROOM: &str = include_str!("../../../../scenes/room.toml");

    fn scene(text: &str) -> Scene {
        Scene::parse(text, Path::new("test.toml"), &SceneOptions::default()).unwrap()
    }

    fn sensor(noise: NoiseModel) -> SimulatedSensor {
        let k = Intrinsics::from_vertical_fov(320, 240, 60.0);
        SimulatedSensor::new(k, 0.4, 6.0, noise, 1).unwrap()
    }

    /// Translation (metres) and rotation (degrees) between two poses.
    fn pose_error(a: &Pose, b: &Pose) -> (f32, f32) {
        let d = a.inverse().compose(b);
        (d.translation.length(), d.rotation_angle().to_degrees())
    }

    /// Tracks `poses` (the first is given) against a perfect map: the scene
    /// itself, rendered from the tracker's last good pose.
    fn track_sequence(scene: &Scene, poses: &[Pose]) -> Vec<Tracked> {
        let mut sensor = sensor(NoiseModel::None);
        let mut tracker =
            Tracker::new(TrackerConfig::default(), sensor.intrinsics, poses[0]).unwrap();
        let mut model_sensor =
            SimulatedSensor::new(tracker.model_intrinsics(), 0.4, 6.0, NoiseModel::None, 1)
                .unwrap();
        poses[1..]
            .iter()
            .map(|pose| {
                let model = model_sensor.capture(scene, 1, &tracker.last_good()).depth;
                let frame = sensor.capture(scene, 1, pose).depth;
                tracker.track_against(&frame, &model)
            })
            .collect()
    }

    #[test]
    fn follows_a_known_motion_within_a_millimetre_and_a_tenth_of_a_degree() {
        let room = scene(ROOM);
        // 2 cm and 1° per frame around the table, rising and tilting.
        let poses: Vec<Pose> = (0..15)
            .map(|i| {
                let a = (i as f32 * 1.0).to_radians();
                let eye = Vec3::new(2.0 * a.cos(), 1.3 + 0.005 * i as f32, 2.0 * a.sin());
                Pose::look_at(eye, Vec3::new(0.0, 0.4 + 0.01 * i as f32, 0.0), Vec3::Y)
            })
            .collect();
        for (tracked, truth) in track_sequence(&room, &poses).iter().zip(&poses[1..]) {
            assert_eq!(tracked.lost, None);
            let (t, r) = pose_error(&tracked.pose, truth);
            assert!(t < 1e-3 && r < 0.1, "error {:.2} mm, {r:.3}°", t * 1e3);
        }
    }

    /// A map that is the scene itself, blind in views narrower than
    /// `blind_below` pixels.
    struct SceneMap<'a> {
        scene: &'a Scene,
        blind_below: u32,
        mesh: crate::mesh::Mesh,
    }

    impl Mapper for SceneMap<'_> {
        fn name(&self) -> &'static str {
            "scene"
        }
        fn integrate(
            &mut self,
            _: &crate::image::Frame,
            _: &Pose,
        ) -> Result<crate::map::IntegrateReport> {
            Ok(Default::default())
        }
        fn render_depth(&self, k: &Intrinsics, pose: &Pose) -> DepthImage {
            if k.width < self.blind_below {
                return DepthImage::new(k.width, k.height);
            }
            let mut sensor = SimulatedSensor::new(*k, 0.4, 6.0, NoiseModel::None, 1).unwrap();
            sensor.capture(self.scene, 1, pose).depth
        }
        fn mesh(&mut self) -> &crate::mesh::Mesh {
            &self.mesh
        }
        fn stats(&self) -> crate::map::MapStats {
            Default::default()
        }
    }

    #[test]
    fn a_frame_the_coarse_view_cannot_align_is_tried_against_a_finer_one() {
        let room = scene(ROOM);
        let k = Intrinsics::from_vertical_fov(640, 480, 60.0);
        let start = Pose::look_at(Vec3::new(2.0, 1.3, 0.0), Vec3::new(0.0, 0.4, 0.0), Vec3::Y);
        let moved = Pose::look_at(
            Vec3::new(2.0, 1.31, 0.02),
            Vec3::new(0.0, 0.4, 0.03),
            Vec3::Y,
        );
        let mut sensor = SimulatedSensor::new(k, 0.4, 6.0, NoiseModel::None, 1).unwrap();
        let frame = sensor.capture(&room, 1, &moved).depth;
        let map = |blind_below| SceneMap {
            scene: &room,
            blind_below,
            mesh: Default::default(),
        };
        // Blind in the quarter-resolution view, sighted at half resolution.
        let mut tracker = Tracker::new(TrackerConfig::default(), k, start).unwrap();
        assert_eq!(tracker.model_intrinsics().width, 160);
        let t = tracker.track(&frame, &map(320));
        assert_eq!(t.lost, None);
        let (dt, dr) = pose_error(&t.pose, &moved);
        assert!(dt < 1e-3 && dr < 0.1, "error {:.2} mm, {dr:.3}°", dt * 1e3);
        // Blind in both: lost, and the tracker stays where it was.
        let mut tracker = Tracker::new(TrackerConfig::default(), k, start).unwrap();
        let t = tracker.track(&frame, &map(u32::MAX));
        assert_eq!(t.lost, Some(LostReason::EmptyModel));
        assert_eq!(t.pose, start);
        assert_eq!(tracker.last_good(), start);
    }

    #[test]
    fn a_camera_lost_while_moving_is_found_again_where_its_motion_led() {
        let room = scene(ROOM);
        let k = Intrinsics::from_vertical_fov(320, 240, 60.0);
        // 5 cm and 1.5° a frame around the room; the map goes blind for
        // frames 4–8, so at frame 9 the camera is 31 cm from its last good
        // pose, beyond the widened search around it.
        let poses: Vec<Pose> = (0..12)
            .map(|i| {
                let a = (i as f32 * 1.5).to_radians();
                let eye = Vec3::new(2.0 * a.cos(), 1.3, 2.0 * a.sin());
                Pose::look_at(eye, Vec3::new(0.0, 0.4, 0.0), Vec3::Y)
            })
            .collect();
        let mut sensor = sensor(NoiseModel::None);
        let mut tracker = Tracker::new(TrackerConfig::default(), k, poses[0]).unwrap();
        for (i, pose) in poses.iter().enumerate().skip(1) {
            let map = SceneMap {
                scene: &room,
                blind_below: if (4..9).contains(&i) { u32::MAX } else { 0 },
                mesh: Default::default(),
            };
            let t = tracker.track(&sensor.capture(&room, 1, pose).depth, &map);
            if (4..9).contains(&i) {
                assert_eq!(t.lost, Some(LostReason::EmptyModel), "frame {i}");
                continue;
            }
            assert_eq!(t.lost, None, "frame {i}");
            let (dt, dr) = pose_error(&t.pose, pose);
            assert!(
                dt < 1e-3 && dr < 0.1,
                "frame {i}: {:.2} mm, {dr:.3}°",
                dt * 1e3
            );
        }
    }

    #[test]
    fn a_single_wall_is_reported_degenerate_instead_of_drifting() {
        let wall = scene("[[object]]\nshape = \"box\"\nsize = [20.0, 20.0, 0.1]\n");
        // Sliding along the wall, 2 m in front of it.
        let poses: Vec<Pose> = (0..4)
            .map(|i| {
                let eye = Vec3::new(0.02 * i as f32, 0.0, 2.0);
                Pose::look_at(eye, eye - Vec3::Z, Vec3::Y)
            })
            .collect();
        let tracked = track_sequence(&wall, &poses);
        for t in &tracked {
            assert!(
                matches!(t.lost, Some(LostReason::Degenerate(_))),
                "{:?}",
                t.lost
            );
            // The last good pose is kept: no drift, nothing non-finite.
            assert_eq!(t.pose, poses[0]);
        }
        assert!(tracked[0].lost.unwrap().to_string().contains("six degrees"));
    }

    #[test]
    fn an_empty_model_is_lost() {
        let mut sensor = sensor(NoiseModel::None);
        let room = scene(ROOM);
        let pose = Pose::look_at(Vec3::new(2.0, 1.3, 0.0), Vec3::ZERO, Vec3::Y);
        let mut tracker = Tracker::new(TrackerConfig::default(), sensor.intrinsics, pose).unwrap();
        let frame = sensor.capture(&room, 1, &pose).depth;
        let k = tracker.model_intrinsics();
        let empty = DepthImage::new(k.width, k.height);
        let t = tracker.track_against(&frame, &empty);
        assert_eq!(t.lost, Some(LostReason::EmptyModel));
        assert_eq!(t.pose, pose);
    }

    #[test]
    fn rejects_bad_settings() {
        let k = Intrinsics::from_vertical_fov(320, 240, 60.0);
        let config = TrackerConfig {
            max_distance: -1.0,
            ..TrackerConfig::default()
        };
        let e = Tracker::new(config, k, Pose::IDENTITY).unwrap_err();
        assert!(e.to_string().contains("max_distance"));
    }
}
