//! Frame-to-model tracking: each frame is aligned by coarse-to-fine ICP
//! against the map's prediction from the last good pose, solving only for
//! the directions the view constrains ([`super::degeneracy`]); a frame that
//! contradicts the map is reported lost and never used, and the camera is
//! then searched for near where it was, turned on the spot there, and,
//! failing that, by global registration against the map's surface
//! ([`super::global_registration`])
//! and from the keyframes most like the frame ([`super::ferns`]), every
//! candidate pose verified against the map before it is accepted (the
//! search is the `search` submodule's).

use super::degeneracy::{Directions, Weak};
use super::ferns::{FernConfig, Keyframes};
use super::filter::{Bilateral, BilateralParams};
use super::free_space::FreeSpace;
use super::global_registration::{GlobalRegistration, MapFeatures};
use super::icp::{
    agreement, agreement_beside, apply_motion, block_equations, equations, facing_information,
    Agreement, Association, Equations,
};
use super::moved_in::MovedIn;
use super::pyramid::{half, Pyramid};
use crate::camera::{Intrinsics, Pose};
use crate::error::{Error, Result};
use crate::image::DepthImage;
use crate::map::Mapper;
use std::fmt;

mod search;

use search::MAX_EXTRAPOLATED;

/// Pyramid levels; the coarsest is 1/4 of the full resolution.
pub const LEVELS: usize = 3;

/// The model view is not made narrower than this by
/// [`TrackerConfig::model_halvings`]: coarser, its depth edges and missing
/// normals cover too much of the frame.
pub const MIN_MODEL_WIDTH: u32 = 160;

/// The view at the frame's resolution that a weak view is aligned again
/// against (see [`TrackerConfig::refine_conditioning`]) takes its normals
/// from neighbours this many pixels apart. One apart, they follow the
/// view's pixel-scale noise, which reads as information along a plane: a
/// camera sliding along a flat wall reported its free directions on two of
/// five frames instead of four. Four apart (the quarter-resolution view's
/// baseline), a small box's edges lose their normals and a floor with one
/// box slid 1.7 and 7.1 m on two of three noise seeds.
const FINE_VIEW_NORMAL_STEP: usize = 2;

/// A followed frame is aligned from its next coarser pyramid level, where
/// that is still at least twice as wide as the model view, when the frame
/// before it left the view conditioned at least this many times
/// [`TrackerConfig::refine_conditioning`]. At full resolution sixteen frame
/// points share each pixel of the quarter-resolution model view, its point
/// and normal; where the view pins every direction, four pin the pose
/// nearly as well for a fifth less of a frame's time (the kitchen's 300
/// frames: an ATE 2 mm larger than at full resolution, the poses at most
/// 1.2 cm apart). Where the view is weak the points left out are what pins
/// it: without the bar, the sofa room's trajectories ended 0.4 cm further
/// off on average over twelve noise seeds, and one camera was lost; with
/// it, 0.2 cm, none lost.
const COARSER_FRAME_CONDITIONING: f64 = 4.0;

/// The iterations a level takes past its schedule (see
/// [`TrackerConfig::settled`]) are kept when they leave the view
/// conditioned, or matched by inliers, at least this many times as well as
/// the schedule left it, or when they settle a large first update (see
/// `EXTRA_ITERATIONS_STEP`); else the schedule's pose stands. They are there to
/// bring in a frame that started centimetres off, in a minimum where part
/// of the scene fits (a turn faster than the last: the floor and a side
/// wall): brought in, more of the scene pins it, 1.5–2.8 times the
/// conditioning in `a_turn_that_speeds_up_is_followed_without_sliding`. In
/// a view that already pinned the frame well, more of the scene agrees
/// without pinning it much better: every 15th kitchen frame (up to 10 cm
/// and 7° from the prediction), judged by conditioning alone, lost three
/// frames of 20, none with the inliers counted too. Iterations that wander
/// along a direction the view barely pins leave the conditioning as it was
/// (1.0–1.05) and match no more of the frame: at the end of a 20 m
/// corridor, where only the floor and the wall are in view, they moved
/// frames centimetres along it without lowering the residual, the motion
/// model took that up, and the straight walks ended 10.78, 13.66 and 6.52
/// cm off instead of 3.32, 3.36 and 3.30 (`bench/track_corridor.sh`, on
/// the code before a first frame's finest level stopped once settled).
const EXTRA_ITERATIONS_GAIN: f64 = 1.25;

/// The iterations past a level's schedule are kept, whatever they do to
/// the conditioning and the points matched, when their first update moves
/// points at least this far (metres) and they settle before their cap:
/// the schedule left the frame centimetres off and a minimum pulled it in.
/// The last frame of `a_turn_that_speeds_up_is_followed_without_sliding`
/// (seed 2) is brought in so by updates of 5.2 cm, 2.8 mm, 0.6 mm and 0.07
/// mm that leave the view conditioned 1.13 times as well and match 1.007
/// times as many points; judged by `EXTRA_ITERATIONS_GAIN` alone, it was
/// left 5 cm short. Iterations that wander along a direction the view
/// barely pins start smaller and do not settle: at the end of the
/// corridor's straight walks (measured before this rule) the first extra
/// update was at most 7.7 mm, and those that ran to the cap wandered up
/// to 25 cm in all.
const EXTRA_ITERATIONS_STEP: f64 = 0.01;

/// A row of the ICP system faces a direction when the cosine between its
/// normal and the way that motion moves its point is at least this (the
/// sine of 20°, the association's default largest angle between normals):
/// a normal tilted off a direction by noise alone stays below it (see
/// [`TrackerConfig::verify_facing`] and [`super::icp::facing_information`]).
const FACING: f64 = 0.34;

/// Directions with an eigenvalue below this fraction of
/// [`TrackerConfig::weak_conditioning`] are not solved for even while
/// iterating: they are numerically singular (a plane's in-plane motion).
const SINGULAR: f64 = 0.01;

/// Without a measured motion, the half-width (in frame pixels, scaled to
/// each model level) of the window searched around a frame point's pixel
/// when projective association finds no model point there (see
/// [`Association::window`]). The simulated sofa room's first frame moved
/// 16 cm with nothing measured: ICP ended 4.6 cm off along the sofa, where
/// only a 4 cm lamp pole pins the camera, and the next frames slid on to
/// 16 cm. With four pixels (1.5–2 cm at 2.5 m) its first frame lands
/// 0.2 cm off; twelve did no better and cost three times as long. Only the
/// frame's own ICP searches it, not relocalisation's from candidate poses:
/// there it left the kitchen's poses found at the map's edge up to 2.9 cm
/// from the references refined against the map, instead of 0.7 cm. Nor
/// does the finest level search it: the coarser levels, searching the same
/// four frame pixels, have brought the frame in, and at full resolution
/// most of what fails at its own pixel fails on the noise of one-pixel
/// normals (a kitchen start: 114 000 of 160 000 points), so the search
/// drew the neighbour whose noise happened to agree, at 40–50 ms an
/// iteration against 5 without it (the first frame 108 ms instead of 215).
const START_WINDOW: usize = 4;

/// Frame pixels along each side of the block that counts as one
/// observation when the data are weighed against the motion model (see
/// [`Tracker::weighed_directions`]): a map of centimetre voxels seen from
/// 1–3 m spans 2–5 pixels a voxel, and its errors are the voxels'.
const INFORMATION_BLOCK: usize = 4;

/// ICP iterations per level, at most: more is a mistake, not a setting.
const MAX_ITERATIONS: usize = 100;

/// The updates a level's iterations are watched over for going round in a
/// cycle (see [`Cycle`]): associations that flip between two or four sets
/// as the pose steps between them (a period of 2 or 4 comes back to the
/// pose it left within this many; a period of 3 to one step from it).
const CYCLE: usize = 4;

/// A pose, followed or found after a loss, is refused when it puts more
/// than this share of the frame's points in space the frames before saw
/// empty ([`crate::track::free_space`]). On the kitchen the camera's own
/// pose puts at most 0.26 % there in a tracked run, and up to 1.2 %
/// in `eval relocalise`, whose map frames are seen from the folder's poses
/// (8.5 cm apart at their worst step); in the jumps bench's look-alike
/// places the refused candidates put 3–10 % there (medians).
const MAX_SEEN_EMPTY: f64 = 0.015;

/// The last [`CYCLE`] poses of a level's iterations and the updates that
/// led to them: whether the iterations go round in a cycle instead of
/// settling. Near a minimum where a few points cross the association's
/// bars, the pose can step back and forth between the sets they make, each
/// update as large as the one before: a kitchen frame followed after a turn
/// stepped 1.5 mm back and forth for the thirty extra iterations a level is
/// allowed (34 iterations in all; the schedule's pose stood), and a
/// kitchen start's coarsest level stepped 0.2 mm round a cycle of four for
/// 55 of its 60 iterations. A level that moves the frame on (a slow pull
/// along what the view barely pins) leaves it about as far from where it
/// was as its updates add up to, and is not a cycle.
struct Cycle {
    poses: [Pose; CYCLE],
    steps: [f64; CYCLE],
    recorded: usize,
}

impl Cycle {
    /// Watches the iterations of a level that starts at `pose`.
    fn starting_at(pose: Pose) -> Self {
        Cycle {
            poses: [pose; CYCLE],
            steps: [0.0; CYCLE],
            recorded: 1,
        }
    }

    /// Records `pose`, reached by an update that moved points `step`
    /// (metres), and returns whether the last [`CYCLE`] updates brought the
    /// frame back within `settled` of where they started, travelling at
    /// least twice as far as that on the way: a cycle, not convergence.
    /// `range` turns rotations into motion of the points, as `step` does.
    fn closes(&mut self, pose: Pose, step: f64, range: f64, settled: f64) -> bool {
        let slot = self.recorded % CYCLE;
        let start = self.poses[slot];
        self.poses[slot] = pose;
        self.steps[slot] = step;
        self.recorded += 1;
        if self.recorded <= CYCLE {
            return false;
        }
        let moved = pose.compose(&start.inverse());
        let net = f64::from(moved.translation.length()) + f64::from(moved.rotation_angle()) * range;
        let travelled: f64 = self.steps.iter().sum();
        net < settled && 2.0 * net < travelled
    }
}

/// Tracking parameters; the defaults are KinectFusion's where it has one,
/// except the iterations: Open3D's (6, 3, 1) track 7-Scenes as accurately
/// as KinectFusion's (10, 5, 4) at a third of the cost.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackerConfig {
    /// ICP iterations per level, coarsest first. The coarsest level runs
    /// only while the motion is not measured (the first frame, after a
    /// loss), when the start may be far off. A coarser level of a followed
    /// frame that has not settled by then goes on (see
    /// [`TrackerConfig::settled`]).
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
    /// Eigen-directions of the ICP system constrained less than this (see
    /// [`super::icp::Equations::conditioning`]) are weak: along them the
    /// data are weighed against the motion model's prediction (see
    /// [`TrackerConfig::motion_sigma`]) instead of followed into the noise
    /// ([`super::degeneracy`]). A weak view is tracked, not lost.
    pub weak_conditioning: f64,
    /// How far the constant-velocity prediction may be off in a frame
    /// (metres; rotations in metres at the points' range): along a weak
    /// direction the data and the prediction are weighed by it and by the
    /// data's own spread ([`super::degeneracy`]); 0 keeps the prediction.
    /// A hand-held or robot-borne camera at 30 Hz changes its velocity by
    /// a few millimetres a frame.
    pub motion_sigma: f64,
    /// A frame aligned against the model view with a conditioning below
    /// this is aligned again against the view at the frame's resolution
    /// (see [`TrackerConfig::model_halvings`]), where thin structures (a
    /// table top's edge, a chair's legs) keep their normals, and the better
    /// conditioned alignment is kept.
    pub refine_conditioning: f64,
    /// Lost when the frame moved more than this from the prediction (metres).
    pub max_jump: f32,
    /// Iterations stop once an update moves points less than this (metres).
    pub convergence: f64,
    /// While following the camera, a level coarser than the finest whose
    /// [`TrackerConfig::iterations`] are spent while its last update still
    /// moved points more than this (metres) goes on until one moves them
    /// less, up to [`TrackerConfig::extra_iterations`] more: the single
    /// finest iteration refines a pose, it cannot finish bringing one in.
    /// A camera turning faster than the motion model predicts (9.3° a
    /// frame after 7°, the scene 2.2 m away) starts ICP about 9 cm off;
    /// with the scheduled iterations alone the frame was left 9.5 cm off,
    /// where the floor and a side wall fit it, and the next two frames
    /// followed it to 29 and 53 cm, nothing reported. A steady camera's
    /// frames settle within the scheduled iterations (the kitchen: 64
    /// more in 300 frames). 0.3 mm is below the depth noise at any range.
    /// The pose the extra iterations reach is kept only if the view pins it
    /// better, or matches more of the frame, than the schedule's (the
    /// tracker's `EXTRA_ITERATIONS_GAIN`), or if they settled a first
    /// update of a centimetre or more (`EXTRA_ITERATIONS_STEP`). The finest
    /// level of a first frame, allowed ten times its iterations, stops
    /// once its scheduled count has run and an update falls below this.
    pub settled: f64,
    /// See [`TrackerConfig::settled`]; 0 keeps to the scheduled iterations.
    pub extra_iterations: usize,
    /// Predict the model view at the frame's resolution halved this many
    /// times: every level of the frame still associates with it, point to
    /// plane, and ray casting is the largest cost of tracking. A frame the
    /// view cannot align, or leaves poorly conditioned (see
    /// [`TrackerConfig::refine_conditioning`]), is tried again against a
    /// view at the frame's own resolution: what pins a view with little
    /// structure (a small box's edges, a chair's legs) keeps its edges and
    /// normals there (a floor with one small box, orbited, drifted 53–105
    /// cm against a view at half resolution, 1.7–4.1 cm against the full
    /// one, on noise seeds 0–2). On
    /// 7-Scenes a quarter (2) tracks as accurately as half resolution (the
    /// same frame-to-frame consistency; ATE 5.26 against 5.38 cm) in a third
    /// of the ray-casting time. Never below [`MIN_MODEL_WIDTH`] pixels.
    pub model_halvings: u32,
    /// The least fraction, of a frame's points that fall on the map's
    /// surface, that must match it (lie within
    /// [`TrackerConfig::verify_distance`] of its surface in the map's view
    /// from the pose found), for every pose, tracked or found again. A
    /// pose found after a loss (near the last pose, by global registration
    /// or from a keyframe) is accepted only if, besides, at least
    /// [`TrackerConfig::verify_overlap`] of all the frame's points match,
    /// the RMS error is within [`TrackerConfig::max_rms`] and no direction
    /// is weak: a wrong pose must never be fused.
    pub verify_inlier_fraction: f64,
    /// The least fraction of a frame's points that must match the map's
    /// surface for a pose found after a loss: the camera may come back
    /// looking half at what the map has not seen (the rest then falls
    /// where the map's view is empty, which contradicts nothing), but not
    /// at a patch of it alone.
    pub verify_overlap: f64,
    /// Distance of a verified match (metres).
    pub verify_distance: f32,
    /// The least information (per inlier, as
    /// [`super::icp::Equations::conditioning`]) that the inliers facing the
    /// weakest direction must carry for a pose found after a loss whose
    /// conditioning is below [`TrackerConfig::refine_conditioning`] (see
    /// [`super::icp::facing_information`]): there the eigenvalue can come
    /// from the noise of normals that do not face it at all. Looking back
    /// along a corridor with bays alike, whose walls and floor explain the
    /// frame wherever it lies along it, poses 4–18 cm off along it were
    /// verified with 0 to 3.1e-5 (conditioning 4.6e-4 to 6.6e-4), the right
    /// ones with 1.7e-4 to 6.4e-3; the kitchen's verified poses are all
    /// conditioned above the bar, so it never applies to them.
    pub verify_facing: f64,
    /// Keyframes for relocalisation.
    pub relocalisation: FernConfig,
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
            weak_conditioning: 3e-5,
            motion_sigma: 0.002,
            refine_conditioning: 2e-3,
            max_jump: 0.3,
            convergence: 1e-5,
            settled: 3e-4,
            extra_iterations: 30,
            model_halvings: 2,
            verify_inlier_fraction: 0.7,
            verify_overlap: 0.3,
            verify_distance: 0.03,
            verify_facing: 1e-4,
            relocalisation: FernConfig::default(),
        }
    }
}

impl TrackerConfig {
    /// Rejects settings that cannot track, naming the field.
    pub fn validate(&self) -> Result<()> {
        let positive = [
            ("max_distance", f64::from(self.max_distance)),
            ("max_rms", self.max_rms),
            ("max_jump", f64::from(self.max_jump)),
            ("verify_distance", f64::from(self.verify_distance)),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::parameter(name, format!("must be positive, got {v}")));
            }
        }
        let ranges = [
            // Normals more than 90° apart face opposite ways.
            (
                "max_normal_angle",
                f64::from(self.max_normal_angle),
                0.0,
                90.0,
            ),
            ("min_inlier_fraction", self.min_inlier_fraction, 0.0, 1.0),
            (
                "verify_inlier_fraction",
                self.verify_inlier_fraction,
                0.0,
                1.0,
            ),
            ("verify_overlap", self.verify_overlap, 0.0, 1.0),
            // 1/3 is the largest smallest eigenvalue (three orthogonal
            // planes); at or above it every direction would be weak.
            ("weak_conditioning", self.weak_conditioning, 0.0, 1.0 / 3.0),
            (
                "refine_conditioning",
                self.refine_conditioning,
                0.0,
                1.0 / 3.0,
            ),
            // Information along one direction, like an eigenvalue.
            ("verify_facing", self.verify_facing, 0.0, 1.0 / 3.0),
            ("convergence", self.convergence, 0.0, 1.0),
            ("settled", self.settled, 0.0, 1.0),
            ("motion_sigma", self.motion_sigma, 0.0, 1.0),
        ];
        for (name, v, lo, hi) in ranges {
            if !(v >= lo && v < hi || name == "max_normal_angle" && v == hi) {
                return Err(Error::parameter(
                    name,
                    format!("must be in [{lo}, {hi:.3}), got {v}"),
                ));
            }
        }
        if self.max_normal_angle <= 0.0 {
            return Err(Error::parameter(
                "max_normal_angle",
                format!("must be positive, got {}", self.max_normal_angle),
            ));
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
        if self.extra_iterations > MAX_ITERATIONS {
            return Err(Error::parameter(
                "extra_iterations",
                format!("at most {MAX_ITERATIONS}, got {}", self.extra_iterations),
            ));
        }
        if let Some(&i) = self.iterations.iter().find(|&&i| i > MAX_ITERATIONS) {
            return Err(Error::parameter(
                "iterations",
                format!("at most {MAX_ITERATIONS} per level, got {i}"),
            ));
        }
        if let Some(b) = &self.bilateral {
            b.validate()?;
        }
        self.relocalisation.validate()
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
    /// Of the frame's points that fall on the map's surface, too few match
    /// it (fraction): the frame sees something else where the map has seen
    /// surface.
    Contradicted(f64),
    /// A pose found after a loss leaves this many directions weakly
    /// constrained: too ambiguous to accept.
    Ambiguous(u8),
    /// The alignment jumped implausibly far from the prediction (metres).
    Jump(f32),
    /// The pose puts this share of the frame's points in space earlier
    /// frames saw empty (see [`crate::track::free_space`]).
    SeenEmpty(f64),
}

impl fmt::Display for LostReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LostReason::EmptyModel => write!(f, "the map predicts no surface from the last pose"),
            LostReason::FewInliers(x) => {
                write!(f, "only {:.0} % of the points match the map", x * 100.0)
            }
            LostReason::LargeError(e) => write!(f, "residual {:.1} mm is too large", e * 1e3),
            LostReason::Contradicted(x) => write!(
                f,
                "only {:.0} % of the points on the map's surface match it",
                x * 100.0
            ),
            LostReason::Ambiguous(n) => write!(
                f,
                "the pose found leaves {n} direction{} weakly constrained, too ambiguous to accept",
                if *n == 1 { "" } else { "s" }
            ),
            LostReason::Jump(d) => {
                write!(f, "the pose jumped {:.0} cm from the prediction", d * 100.0)
            }
            LostReason::SeenEmpty(x) => write!(
                f,
                "{:.1} % of the points lie in space earlier frames saw empty",
                x * 100.0
            ),
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
    /// RMS distance of the matches at the finest level from the camera
    /// (metres; see [`super::icp::Equations::rms_range`]).
    pub range: f64,
    /// ICP iterations run, all levels and attempts.
    pub iterations: usize,
    /// Directions the view left weak, where the motion model weighed more
    /// than the data (0–6).
    pub weak_directions: u8,
    /// The axes those directions move along most (bits of
    /// [`super::degeneracy::AXES`]; [`super::degeneracy::axes_label`]
    /// names them).
    pub weak_axes: u8,
    /// The pose was found after the camera was lost by the search's turns
    /// on the spot, global registration or a keyframe.
    pub relocalised: bool,
    /// Why following lost this frame, when the search for the lost camera
    /// then found it (see [`Tracker::track`]): it is not lost.
    pub recovered_from: Option<LostReason>,
    /// The frame is lost for space seen empty but was followed on from its
    /// pose, having kept its course: something in view where earlier
    /// frames saw through, such as a person walking in, more likely than a
    /// lost camera. Held frames are searched for on the 8th, 16th, 32nd…
    /// in a row.
    pub held: bool,
    /// How far (metres) the pose lies from the prediction it was aligned
    /// from: the motion from the last good pose, or no motion.
    pub deviation: f32,
}

impl Tracked {
    /// Whether ICP aligned the frame with the map's view, though the pose
    /// may put its points in space seen empty: another view would align
    /// it no better, and a frame held for that
    /// ([`Tracker::hold`]) should cost what a followed one does.
    fn aligned(&self) -> bool {
        matches!(self.lost, None | Some(LostReason::SeenEmpty(_)))
    }

    /// A frame the map's view gave nothing to align with.
    fn empty(pose: Pose) -> Tracked {
        Tracked {
            pose,
            lost: Some(LostReason::EmptyModel),
            inlier_fraction: 0.0,
            rms: 0.0,
            conditioning: 0.0,
            range: 0.0,
            iterations: 0,
            weak_directions: 0,
            weak_axes: 0,
            relocalised: false,
            recovered_from: None,
            held: false,
            deviation: 0.0,
        }
    }
}

/// How an ICP run starts and is judged.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Search {
    /// Tracking: from the motion model, judged against the prediction.
    Follow,
    /// After a loss, near the last good pose: wider associations and
    /// jumps, more coarse iterations, and the result verified.
    Recover,
    /// From a keyframe's pose: as [`Search::Recover`], but with no
    /// prediction to jump from.
    Relocalise,
    /// Ranking many starts cheaply: as [`Search::Relocalise`], on the
    /// coarsest frame level alone, against a view rendered at half the
    /// model's resolution (whose second level is as fine as the model's
    /// coarsest), verified at that level.
    Screen,
}

/// What a [`Tracker`] carries from frame to frame.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackerState {
    /// The last pose tracked successfully.
    pub last_good: Pose,
    /// Motion between the last two good frames (after a loss, the mean
    /// step across it; see `velocity_known`).
    pub velocity: Pose,
    /// Frames lost since the last good one.
    pub lost_streak: usize,
    /// Frame intervals from the last good frame to the last frame seen
    /// (dropped frames count: see [`Tracker::track_after`]).
    pub since_good: usize,
    /// Frames followed but not fused since the last fused one (see
    /// `Tracker::hold`).
    pub held_streak: usize,
    /// Whether `velocity` was measured between consecutive frames.
    pub velocity_known: bool,
    /// Whether the next frame is tried against the frame-resolution view
    /// before the coarse one.
    pub fine_first: bool,
    /// The conditioning of the last frame's alignment (0 after a loss).
    pub last_conditioning: f64,
    /// Relocalisation keyframes: fern codes back to back.
    pub keyframe_codes: Vec<u8>,
    /// Their poses.
    pub keyframe_poses: Vec<Pose>,
    /// The space the frames so far saw empty, which a pose found after a
    /// loss is held to: without it a resumed run would take the camera to
    /// a place an uninterrupted one refuses.
    pub free_space: FreeSpace,
}

impl TrackerState {
    /// A tracker's state at `last_good`, moving by the measured `velocity`
    /// (camera-to-camera, per frame), with no keyframes.
    pub fn moving(last_good: Pose, velocity: Pose) -> Self {
        TrackerState {
            last_good,
            velocity,
            lost_streak: 0,
            since_good: 0,
            held_streak: 0,
            velocity_known: true,
            fine_first: false,
            last_conditioning: 0.0,
            keyframe_codes: Vec::new(),
            keyframe_poses: Vec::new(),
            free_space: FreeSpace::default(),
        }
    }
}

/// Frame-to-model ICP tracker with a constant-velocity motion model and
/// keyframe relocalisation.
#[derive(Debug)]
pub struct Tracker {
    config: TrackerConfig,
    intrinsics: Intrinsics,
    /// The camera model of the model view.
    model_intrinsics: Intrinsics,
    /// The model view at the frame's resolution, which a frame is tried
    /// against when the first cannot align it or leaves it poorly
    /// conditioned (`None` when the model view is already at it).
    fallback_intrinsics: Option<Intrinsics>,
    filter: Option<Bilateral>,
    filtered: DepthImage,
    frame: Pyramid,
    model: Pyramid,
    last_good: Pose,
    /// Motion between the last two consecutive good frames (camera-to-camera);
    /// after a loss, the start of the frame after it
    /// ([`Tracker::motion_across_loss`]).
    velocity: Pose,
    /// Frames lost since the last good one.
    lost_streak: usize,
    /// Frame intervals from the last good frame to the frame being
    /// tracked: the steps of `velocity` that predict it.
    since_good: usize,
    /// Frames followed but held back from fusion since the last one fused
    /// ([`Tracker::hold`]).
    held_streak: usize,
    /// Whether `velocity` was measured (false at the start and after a
    /// loss): without it, ICP starts from no motion and may need to travel
    /// far, so the coarsest level gets more iterations.
    velocity_known: bool,
    /// The last frame followed was weak even against the frame-resolution
    /// view: the next is aligned against that view alone (the coarse one
    /// only if it cannot align it), which saves the coarse try a weak scene
    /// fails frame after frame.
    fine_first: bool,
    /// The conditioning of the last frame's alignment (0 after a loss or
    /// at the start); see [`COARSER_FRAME_CONDITIONING`].
    last_conditioning: f64,
    keyframes: Keyframes,
    /// The map's surface seen from the keyframes, described for global
    /// registration; made when first needed, grown as keyframes are learnt.
    map_features: MapFeatures,
    /// The space the frames concluded so far saw empty, for verifying a
    /// pose found after a loss.
    free_space: FreeSpace,
    /// Where the last frame, if held, saw something in that space: the
    /// next frame is not held to the map's surface it hides there.
    moved_in: MovedIn,
    registration: GlobalRegistration,
}

impl Tracker {
    /// A tracker for frames from `intrinsics`, starting at `start`.
    pub fn new(config: TrackerConfig, intrinsics: Intrinsics, start: Pose) -> Result<Self> {
        config.validate()?;
        intrinsics.validate()?;
        let model_intrinsics = (0..config.model_halvings).fold(intrinsics, |k, _| {
            if k.width / 2 >= MIN_MODEL_WIDTH {
                half(&k)
            } else {
                k
            }
        });
        Ok(Tracker {
            filter: config.bilateral.map(Bilateral::new).transpose()?,
            keyframes: Keyframes::new(config.relocalisation)?,
            map_features: MapFeatures::default(),
            free_space: FreeSpace::default(),
            moved_in: MovedIn::default(),
            registration: GlobalRegistration::default(),
            model_intrinsics,
            fallback_intrinsics: (intrinsics != model_intrinsics).then_some(intrinsics),
            config,
            intrinsics,
            filtered: DepthImage::default(),
            frame: Pyramid::default(),
            model: Pyramid::default(),
            last_good: start,
            velocity: Pose::IDENTITY,
            lost_streak: 0,
            since_good: 0,
            held_streak: 0,
            velocity_known: false,
            fine_first: false,
            last_conditioning: 0.0,
        })
    }

    /// What the tracker carries from frame to frame, to save and restore
    /// (the rest is made again from each frame and the map).
    pub fn state(&self) -> TrackerState {
        let (codes, poses) = self.keyframes.saved();
        TrackerState {
            last_good: self.last_good,
            velocity: self.velocity,
            lost_streak: self.lost_streak,
            since_good: self.since_good,
            held_streak: self.held_streak,
            velocity_known: self.velocity_known,
            fine_first: self.fine_first,
            last_conditioning: self.last_conditioning,
            keyframe_codes: codes.to_vec(),
            keyframe_poses: poses.to_vec(),
            free_space: self.free_space.clone(),
        }
    }

    /// A tracker that goes on from `state` (see [`Tracker::state`]).
    pub fn restore(
        config: TrackerConfig,
        intrinsics: Intrinsics,
        state: TrackerState,
    ) -> Result<Self> {
        let mut t = Tracker::new(config, intrinsics, state.last_good)?;
        t.velocity = state.velocity;
        t.lost_streak = state.lost_streak;
        t.since_good = state.since_good;
        t.held_streak = state.held_streak;
        t.velocity_known = state.velocity_known;
        t.fine_first = state.fine_first;
        t.last_conditioning = state.last_conditioning;
        t.keyframes
            .restore(state.keyframe_codes, state.keyframe_poses)?;
        t.free_space = state.free_space;
        Ok(t)
    }

    /// The last pose that was tracked successfully (or the start).
    pub fn last_good(&self) -> Pose {
        self.last_good
    }

    /// Keyframes learnt for relocalisation so far.
    pub fn keyframes(&self) -> usize {
        self.keyframes.len()
    }

    /// Aligns `depth` with what `map` predicts from the last good pose;
    /// when that loses the camera, or it was lost before, searches for it
    /// near its last pose, then turned on the spot there, then by global
    /// registration against the map and from the keyframes most like the
    /// frame.
    ///
    /// The search starts at the frame following loses, not at the next
    /// one: the camera that jumped is found where it landed, and that
    /// frame is fused instead of thrown away (every gap of the kitchen in
    /// the README lost exactly that frame, and tracking every 20th frame
    /// of the kitchen lost two such frames).
    pub fn track(&mut self, depth: &DepthImage, map: &dyn Mapper) -> Tracked {
        self.track_after(depth, 1, map)
    }

    /// [`Tracker::track`] for a frame taken `steps` frame intervals after
    /// the last one (2 when the sensor dropped one; see
    /// [`crate::track::clock`]): the motion model predicts it that many
    /// frames on. Beyond 15 frames (half a second at 30 Hz) the last
    /// motion says little of where the camera is, and the frame is looked
    /// for as the first after a loss is.
    pub fn track_after(&mut self, depth: &DepthImage, steps: usize, map: &dyn Mapper) -> Tracked {
        self.since_good += steps.max(1);
        if self.since_good > MAX_EXTRAPOLATED {
            self.velocity_known = false;
        }
        self.prepare(depth);
        if self.lost_streak > 0 {
            let (near, axes) = self.look_near(map);
            let found = self.search_on(map, near, axes);
            return self.conclude(found, true);
        }
        // The frame after the camera was found again is first looked for
        // as a lost one is, near its last pose from the step across the
        // loss and from no motion, under the search's verification; only
        // if that fails is it followed from both ([`Tracker::start_still`]).
        // Found in the frame following lost it, the step across is one
        // frame's, and from it following's jump bar sent the next frames
        // on to the full search: every 20th kitchen frame, three searched
        // for in a row, 263 ms of tracking a frame, against two and 140 ms
        // this way. Held to the search's verification alone, frames of the
        // table scene after a jump were lost over and over for a weak
        // direction that following takes from the motion model.
        let mut looked = None;
        if !self.velocity_known && !self.keyframes.is_empty() {
            let (near, axes) = self.look_near(map);
            if near.lost.is_none() {
                return self.conclude(near, false);
            }
            looked = Some((near, axes));
        }
        let followed = self.follow(map);
        let held = matches!(followed.lost, Some(LostReason::SeenEmpty(_)))
            && self.kept_its_course(&followed);
        // A held frame kept its course, so it is as likely where the camera
        // is as any frame followed; the search, which costs about what a
        // hundred followed frames do in the simulated room, is the way out
        // should it not be, tried on the eighth held frame in a row, the
        // sixteenth, the thirty-second… (something that moved into view
        // may stay there for seconds).
        let searched = (self.held_streak + 1).is_power_of_two() && self.held_streak + 1 >= 8;
        if held && !searched {
            return self.hold(followed);
        }
        let Some(reason) = followed.lost else {
            let before = looked.map_or(0, |(near, _)| near.iterations);
            let followed = Tracked {
                iterations: followed.iterations + before,
                ..followed
            };
            return self.conclude(followed, false);
        };
        // The search goes on from the look near the last pose, if it was
        // taken: following does not change what it finds.
        let (near, axes) = match looked {
            Some(looked) => looked,
            None => self.look_near(map),
        };
        let found = self.search_on(map, near, axes);
        let iterations = followed.iterations + found.iterations;
        // A frame still lost reads as following lost it: why the search
        // failed too says less than why the camera was lost.
        let result = match found.lost {
            None => Tracked {
                iterations,
                recovered_from: Some(reason),
                ..found
            },
            Some(_) => Tracked {
                iterations,
                ..followed
            },
        };
        if found.lost.is_some() && held {
            return self.hold(result);
        }
        self.conclude(result, true)
    }

    /// A followed frame that puts its points in space seen empty, where the
    /// search, if it ran, found no pose that does not: not fused, but
    /// followed on from the pose found. Something may have moved into view at that pose (a
    /// person walking into the room): the next frames are followed as
    /// before, and fused again once it is gone. Or the pose is a place
    /// that only looks like the camera's: the next frames, still there, are
    /// held too, and searched for, until the search finds the camera.
    ///
    /// Only a frame that kept its course ([`Tracker::kept_its_course`]) is
    /// held; one that did not is lost, as any frame following loses.
    fn hold(&mut self, result: Tracked) -> Tracked {
        // The pose is following's, as a fused frame's would be.
        self.learn_motion(&result, false);
        self.moved_in.clear();
        let seen = &self.frame.levels[1];
        let moved_in = &mut self.moved_in;
        self.free_space
            .points_inside(&seen.points, seen.size().0, &result.pose, |p| {
                moved_in.mark(p)
            });
        self.last_good = result.pose;
        self.since_good = 0;
        self.last_conditioning = result.conditioning;
        self.held_streak += 1;
        Tracked {
            held: true,
            ..result
        }
    }

    /// Whether `followed` lies within the verification distance of where
    /// it was predicted, from the motion or from no motion (when the frame
    /// after the camera was found again was aligned from both,
    /// [`Tracker::start_still`]). A camera carried
    /// across a jump to a place that only looks like its own got there by
    /// leaving its course (the chairs, 0.8 m on round the orbit: 6.4 cm
    /// from the prediction, where the kitchen's frames stay within 1.6 cm
    /// of it); something moving into view leaves the camera on it.
    fn kept_its_course(&self, followed: &Tracked) -> bool {
        followed.deviation <= self.config.verify_distance
    }

    /// Where the motion model puts the frame being tracked, from the last
    /// good pose: `velocity` once a frame, as many times as frame
    /// intervals passed when the velocity was measured (frames the sensor
    /// dropped while the camera moved on).
    fn predicted(&self) -> Pose {
        let steps = if self.velocity_known {
            self.since_good
        } else {
            1
        };
        self.velocity.power(steps)
    }

    /// The camera model [`Tracker::track_against`] expects the model view in.
    pub fn model_intrinsics(&self) -> Intrinsics {
        self.model_intrinsics
    }

    /// Aligns `depth` with `model`, the map's depth seen from the last good
    /// pose with [`Tracker::model_intrinsics`] (no finer view, no
    /// relocalisation: there is no map to ask).
    pub fn track_against(&mut self, depth: &DepthImage, model: &DepthImage) -> Tracked {
        self.since_good += 1;
        self.prepare(depth);
        let searching = self.lost_streak > 0;
        let result = if !self.model_view(model, self.model_intrinsics) {
            Tracked::empty(self.last_good)
        } else if searching {
            self.search_near()
        } else {
            self.icp(self.last_good, self.velocity, Search::Follow)
        };
        self.conclude(result, searching)
    }

    /// Learns `depth`, seen from `pose` (known, e.g. from the data), for
    /// relocalisation: its rays as space seen empty, and the frame as a
    /// keyframe unless one like it is known; whether it was learnt as one.
    /// The tracking state is unchanged.
    pub fn learn_view(&mut self, depth: &DepthImage, pose: &Pose) -> bool {
        self.prepare(depth);
        self.free_space.add_view(&self.frame.levels[0], pose);
        self.keyframes
            .learn(&self.frame.levels[LEVELS - 1].depth, pose)
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

    /// Builds the model pyramid from `model` (seen with `k`); whether it
    /// has any surface to align with.
    fn model_view(&mut self, model: &DepthImage, k: Intrinsics) -> bool {
        self.model_view_spaced(model, k, 1)
    }

    /// [`Tracker::model_view`] with normals from neighbours `step` pixels
    /// apart (see [`Pyramid::build_spaced`]).
    fn model_view_spaced(&mut self, model: &DepthImage, k: Intrinsics, step: usize) -> bool {
        self.model.build_spaced(model, &k, LEVELS, step);
        self.model.levels[0]
            .normals
            .iter()
            .any(|n| *n != glam::Vec3::ZERO)
    }

    /// Tracking: the frame against the map's view from the last good pose,
    /// then against its view at the frame's resolution if the first cannot
    /// align it or leaves it poorly conditioned; the better of the two.
    /// Once a frame is poorly conditioned in both, the next ones go to the
    /// frame-resolution view alone (the coarse one only if that cannot
    /// align them) until one is well conditioned there.
    ///
    /// Without a measured motion (the first frame, and the first after the
    /// camera was found again), against the view at the frame's own
    /// resolution alone; before the first keyframe, also weighed against
    /// the poses global registration proposes ([`Tracker::start_globally`]);
    /// after a loss, from the step across it and from no motion
    /// ([`Tracker::start_still`]).
    fn follow(&mut self, map: &dyn Mapper) -> Tracked {
        let mut result = self.follow_from(map, self.predicted());
        // Only before the first keyframe (the start): after the camera is
        // found again, its pose was verified against the map a frame ago,
        // and weighing global registration's poses means describing the map
        // from every keyframe anew (0.55 s of that frame's 0.78 s on the
        // corridor walked there and back; without it, those walks and the
        // kitchen's seven gaps of the README gave the same poses' errors
        // to the last digit).
        //
        // A start ICP aligned with its view well conditioned is kept
        // without asking global registration (60–70 ms of a kitchen run's
        // first frame): over 116 simulated first frames (seven scenes,
        // seeds 0–11; sixteen random scenes, seeds 0–1) its poses were
        // never taken, and the kitchen's trajectories stay the same without
        // them; a start that is lost or weak still gets them.
        if self.at_start() {
            if !self.aligned_well(&result) {
                result = self.start_globally(map, result);
            }
        } else if !self.velocity_known && self.velocity != Pose::IDENTITY {
            result = self.start_still(map, result);
        }
        result
    }

    /// Whether the run is at its start: no motion measured and no keyframe
    /// yet, so "no motion" from the frame before is the only guess.
    fn at_start(&self) -> bool {
        !self.velocity_known && self.keyframes.is_empty()
    }

    /// Whether `t` was aligned, and conditioned at least as well as
    /// [`TrackerConfig::refine_conditioning`] asks: no other view or start
    /// is tried for it.
    fn aligned_well(&self, t: &Tracked) -> bool {
        t.aligned() && t.conditioning >= self.config.refine_conditioning
    }

    /// [`Tracker::follow`]'s alignment from `predicted` (the motion from
    /// the last good pose), against one view or two.
    fn follow_from(&mut self, map: &dyn Mapper, predicted: Pose) -> Tracked {
        let mut best: Option<Tracked> = None;
        let mut iterations = 0;
        // The first frame may have moved a tenth of the view from the
        // start, and what pins it along the view (a table's legs and edges,
        // seen nearly edge-on) is a few pixels wide in a coarser view: the
        // table scene's first frame landed 3–4 cm off against the quarter
        // and half resolution views, within a millimetre against the full
        // one. It is one frame in a run or after a loss, so the larger ray
        // cast costs little.
        let coarse = Some((self.model_intrinsics, 1));
        let fine = self.fallback_intrinsics.map(|k| (k, FINE_VIEW_NORMAL_STEP));
        let fine_first = self.velocity_known && self.fine_first && fine.is_some();
        let views = match (self.velocity_known, fine_first) {
            (true, false) => [coarse, fine],
            (true, true) => [fine, coarse],
            (false, _) => [Some((self.intrinsics, 1)), None],
        };
        // Whether the fine view was tried and left the frame weak too, and
        // whether the coarse one aligned it well (after the fine one could
        // not): then the next frame goes back to the coarse view first.
        let (mut fine_weak, mut coarse_good) = (false, false);
        for (k, step) in views.into_iter().flatten() {
            let model = map.render_depth(&k, &self.last_good);
            if !self.model_view_spaced(&model, k, step) {
                continue;
            }
            let t = self.icp(self.last_good, predicted, Search::Follow);
            iterations += t.iterations;
            let better = best.is_none_or(|b| {
                (t.lost.is_none(), t.aligned(), t.conditioning)
                    > (b.lost.is_none(), b.aligned(), b.conditioning)
            });
            if better {
                best = Some(t);
            }
            let good = self.aligned_well(&t);
            let is_coarse = k == self.model_intrinsics;
            fine_weak |= !is_coarse && !good;
            coarse_good |= is_coarse && good;
            // After a weak frame the coarse view is tried only if the fine
            // one cannot align the frame: where every frame is weak (the
            // table, a floor with a box, the chairs, the open space) the
            // fine view's pose was the one kept on every frame, and
            // skipping the coarse try left their trajectories unchanged to
            // the last digit.
            if good || (fine_first && t.aligned()) {
                break;
            }
        }
        let mut result = best.unwrap_or(Tracked::empty(self.last_good));
        self.fine_first = self.velocity_known && fine_weak && !coarse_good;
        result.iterations = iterations;
        result
    }

    /// The frame after the camera was found again starts from the mean
    /// step across the loss ([`Tracker::motion_across_loss`]): a camera that walks
    /// on while it is lost walks on after it, and from no motion, along
    /// what the view pins only at its edges (a corridor of bays alike, the
    /// camera walking 10 cm a frame), ICP stayed where the last frame was
    /// and every frame after it followed (9 and 30 cm off). But the loss
    /// may have been a stop, or the mean a poor guess, so `moving` is
    /// weighed against the frame aligned from no motion, as
    /// [`Tracker::start_globally`] weighs its poses. Even a well
    /// conditioned `moving` is weighed: skipping it then (tried) left the
    /// kitchen's gap of frames 200–279 with a second lost frame and its
    /// ATE at 6.86 cm instead of 5.25, for 0.2 s saved on that one frame.
    fn start_still(&mut self, map: &dyn Mapper, moving: Tracked) -> Tracked {
        let still = self.follow_from(map, Pose::IDENTITY);
        self.better_of(map, moving, still)
    }

    /// Coarse-to-fine ICP of the prepared frame against the model pyramid,
    /// seen from `base`, starting from the frame motion `predicted` (from
    /// `base`), and the verdict on its result, whose pose is absolute.
    fn icp(&self, base: Pose, predicted: Pose, search: Search) -> Tracked {
        self.align(base, predicted, search).0
    }

    /// How many frame levels coarser than the model view's each level is
    /// paired with: one or more while the camera is followed and the frame
    /// before left the view well conditioned (see
    /// [`COARSER_FRAME_CONDITIONING`]), as far as the frame level stays at
    /// least twice the model view's width; else none.
    fn frame_coarsening(&self, recovering: bool) -> usize {
        if recovering
            || !self.velocity_known
            || self.last_conditioning < COARSER_FRAME_CONDITIONING * self.config.refine_conditioning
        {
            return 0;
        }
        let model_width = self.model.levels[0].size().0;
        (1..LEVELS)
            .take_while(|&l| self.frame.levels[l].size().0 >= 2 * model_width)
            .count()
    }

    /// [`Tracker::icp`], with the frame's agreement with the map's view at
    /// the pose found when it was verified (after a loss; default else).
    fn align(&self, base: Pose, predicted: Pose, search: Search) -> (Tracked, Agreement) {
        let recovering = search != Search::Follow;
        // Screening runs the coarsest frame level alone, against a view
        // rendered at half the model's resolution, whose levels are one
        // step coarser than the model's; it is verified at that level.
        let screening = search == Search::Screen;
        let (model_step, verified_level) = if screening { (1, LEVELS - 1) } else { (0, 1) };
        let widen = if recovering { 2.0 } else { 1.0 };
        let assoc = Association {
            max_distance: self.config.max_distance * widen,
            min_normal_cos: self.config.max_normal_angle.to_radians().cos(),
            // Without a measured motion the start can be far off, and a
            // floor filling the view pulls the frame into the nearest
            // minimum: every orientation gets the same say.
            balance: !self.velocity_known,
            window: 0,
        };
        let frame_width = self.intrinsics.width as usize;
        let coarser = self.frame_coarsening(recovering);
        let mut relative = predicted;
        let mut iterations = 0;
        // The last system solved: the alignment is judged by it (its
        // update, at convergence, is below the noise).
        let mut eq = Equations::default();
        let floor = self.config.weak_conditioning * SINGULAR;
        for (level, &count) in (0..LEVELS).rev().zip(&self.config.iterations) {
            // Without a measured motion the start can be far off, and the
            // coarsest level alone is too coarse to bring the frame in
            // (a table is a few pixels there): every level may take ten
            // times as many iterations. What they do not need, convergence
            // leaves unused.
            //
            // With a measured motion the prediction is within centimetres
            // and the coarsest level is left out: the model view's coarsest
            // level (40×30 pixels at a quarter of the frame's resolution)
            // keeps normals on little but the floor, and along what it
            // barely constrains it follows aliasing, not the frame (a desk
            // seen end-on, against a map fused from the true poses, slid
            // 9 cm in one frame).
            let runs = match (level == LEVELS - 1, recovering, self.velocity_known) {
                (false, _, _) if screening => 0,
                (true, true, _) => 2 * count,
                (true, false, true) => 0,
                (_, false, false) => 10 * count,
                _ => count,
            };
            let model = &self.model.levels[level.saturating_sub(model_step)];
            let assoc = Association {
                window: if self.velocity_known || recovering || level == 0 {
                    0
                } else {
                    (START_WINDOW * model.size().0 + frame_width / 2) / frame_width
                },
                ..assoc
            };
            let most = if runs > 0 && level > 0 && !recovering {
                runs + self.config.extra_iterations
            } else {
                runs
            };
            // The finest level of a first frame may stop at its scheduled
            // count once an update moves points less than the noise: the
            // coarser levels brought the frame in, and the ten-fold
            // allowance is for a start that is far off, not for polishing
            // a pose that has settled.
            let enough = if level == 0 { runs.min(count) } else { runs };
            // The pose and system where the schedule ended, if the level
            // went on past it, and the first extra update.
            let mut scheduled: Option<(Pose, Equations, f64)> = None;
            let mut settled_past_schedule = false;
            let frame = &self.frame.levels[(level + coarser).min(LEVELS - 1)];
            let mut cycle = Cycle::starting_at(relative);
            for run in 1..=most {
                eq = equations(frame, model, &relative, &assoc);
                iterations += 1;
                let Some(directions) = Directions::of(&eq) else {
                    break;
                };
                let (omega, t) = directions.solve(floor);
                let previous = relative;
                relative = apply_motion(&relative, omega, t);
                let rotation = omega.iter().map(|w| w * w).sum::<f64>().sqrt();
                let translation = t.iter().map(|v| v * v).sum::<f64>().sqrt();
                let step = translation + rotation * eq.rms_range();
                if run == runs + 1 {
                    scheduled = Some((previous, eq, step));
                }
                if step < self.config.convergence || run >= enough && step < self.config.settled {
                    settled_past_schedule = run > runs;
                    break;
                }
                // Past the level's scheduled count (not its allowance), a
                // cycle is left where it is: it has not settled, so
                // iterations past the schedule are judged as if they had
                // run out.
                let cycled = cycle.closes(relative, step, eq.rms_range(), self.config.settled);
                if cycled && run >= count {
                    break;
                }
            }
            if let Some((pose, at, first_step)) = scheduled {
                let brought_in = settled_past_schedule && first_step >= EXTRA_ITERATIONS_STEP;
                if !brought_in
                    && eq.conditioning() < EXTRA_ITERATIONS_GAIN * at.conditioning()
                    && (eq.inliers as f64) < EXTRA_ITERATIONS_GAIN * at.inliers as f64
                {
                    (relative, eq) = (pose, at);
                }
            }
        }
        // What the view leaves weak at the pose found goes back to the
        // prediction, if there is one. Without a measured motion "no
        // motion" is a guess, not a prediction, but at the start of a run
        // it is where the frame before was taken from, and along what the
        // view barely pins, ICP from it follows the few rows at the edges
        // of what pins the rest: a camera slid 2.5–4 cm along a wall, a
        // post in front of it pinning all but the height, was fused 19–23
        // cm up the wall, nothing reported. So there what the view leaves
        // weak stays at the guess too, unless ICP left free went further
        // from it than a frame is followed ([`TrackerConfig::max_jump`]):
        // that frame is lost as before, not fused beside the guess with
        // what pinned it out of view.
        let directions = self.weighed_directions(&eq, &relative, &assoc, recovering);
        let (weak_conditioning, motion_sigma) =
            (self.config.weak_conditioning, self.config.motion_sigma);
        let weak = directions.map_or(Weak::default(), |d| d.weak(weak_conditioning, motion_sigma));
        let starting = search == Search::Follow
            && self.at_start()
            && (relative.translation - predicted.translation).length() <= self.config.max_jump;
        let predicts = self.velocity_known || recovering || starting;
        if let (Some(d), true) = (directions, weak.count > 0 && predicts) {
            let moved = relative.compose(&predicted.inverse());
            let omega = moved.quat().to_scaled_axis();
            let t = moved.translation;
            let (omega, t) = d.without_weak(
                (
                    [omega.x, omega.y, omega.z].map(f64::from),
                    [t.x, t.y, t.z].map(f64::from),
                ),
                weak_conditioning,
                motion_sigma,
            );
            relative = apply_motion(&predicted, omega, t);
        }
        let mut inlier_fraction = eq.inliers as f64 / eq.candidates.max(1) as f64;
        let mut rms = eq.rms();
        let jump = (relative.translation - predicted.translation).length();
        // After a loss only the verification below judges the data.
        let mut lost = if recovering {
            None
        } else if inlier_fraction < self.config.min_inlier_fraction {
            Some(LostReason::FewInliers(inlier_fraction))
        } else if rms > self.config.max_rms {
            Some(LostReason::LargeError(rms))
        } else if jump > self.config.max_jump {
            Some(LostReason::Jump(jump))
        } else {
            None
        };
        // Depth agreement at the pose found: the frame at half resolution
        // (at its coarsest when screening) against the finest model level.
        let verify = || {
            agreement(
                &self.frame.levels[verified_level],
                &self.model.levels[0],
                &relative,
                self.config.verify_distance,
            )
        };
        let mut agree = Agreement::default();
        if search == Search::Recover && jump > self.config.max_jump * widen {
            lost = Some(LostReason::Jump(jump));
        } else if recovering {
            agree = verify();
            (inlier_fraction, rms) = (agree.overlap, agree.rms);
            lost = if agree.overlap < self.config.verify_overlap {
                Some(LostReason::FewInliers(agree.overlap))
            } else if agree.on_surface < self.config.verify_inlier_fraction {
                Some(LostReason::Contradicted(agree.on_surface))
            } else if let Some(empty) =
                self.seen_empty(verified_level, &base.compose(&relative), screening)
            {
                Some(LostReason::SeenEmpty(empty))
            } else if rms > self.config.max_rms {
                Some(LostReason::LargeError(rms))
            } else if weak.count > 0 {
                Some(LostReason::Ambiguous(weak.count))
            // A screened pose is ranked by its overlap alone, never taken.
            } else if !screening
                && eq.conditioning() < self.config.refine_conditioning
                && directions.is_some_and(|d| {
                    facing_information(
                        &self.frame.levels[verified_level],
                        &self.model.levels[0],
                        &relative,
                        &assoc,
                        d.weakest(),
                        FACING,
                    ) < self.config.verify_facing
                })
            {
                Some(LostReason::Ambiguous(1))
            } else {
                None
            };
        } else if lost.is_none() {
            // A tracked pose is held to the same agreement with the map
            // where the map has seen surface: a camera that turns about in
            // one frame can leave ICP where the floor and a third of the
            // frame fit, above the inlier bar, and every frame after it
            // then follows that pose (a corridor walked there and back:
            // 4.7 m off by the end, nothing reported lost). Frames tracked
            // well match 92 % or more of those points (the kitchen's 300
            // frames, noise seed 0 of every simulated scene of the README's
            // tracking table); that frame matched 44 %.
            //
            // It is held to the space earlier frames saw empty too: a
            // camera that jumps can be followed to a place that looks the
            // same from there, matching the map's view as well as the
            // camera's own (the chairs, 0.7 m on round the orbit: 86 % on
            // the surface, 8 % of the points in space seen empty), and
            // every frame after it is then fused there. Frames followed
            // right put at most 0.5 % there (the kitchen's 300, the scenes
            // of the README's tracking table, a random clutter of three
            // seeds).
            //
            // Where the frame before was held for something that moved
            // into view, what stands in front of the surface there is not
            // counted: it hides the surface (a person crossing a quarter
            // of the view, 1 m ahead, lost a camera held right on for
            // twelve frames).
            agree = if self.moved_in.is_empty() {
                verify()
            } else {
                agreement_beside(
                    &self.frame.levels[verified_level],
                    &self.model.levels[0],
                    &relative,
                    self.config.verify_distance,
                    |q| self.moved_in.covers(base.transform_point(q)),
                )
            };
            if agree.on_surface < self.config.verify_inlier_fraction {
                lost = Some(LostReason::Contradicted(agree.on_surface));
            } else if let Some(empty) =
                self.seen_empty(verified_level, &base.compose(&relative), screening)
            {
                lost = Some(LostReason::SeenEmpty(empty));
            }
        }
        let tracked = Tracked {
            pose: base.compose(&relative),
            lost,
            inlier_fraction,
            rms,
            conditioning: eq.conditioning(),
            range: eq.rms_range(),
            iterations,
            weak_directions: weak.count,
            weak_axes: weak.axes,
            relocalised: false,
            recovered_from: None,
            held: false,
            deviation: jump,
        };
        (tracked, agree)
    }

    /// The share of the frame's points (level `level`) that the pose
    /// `pose` (camera-to-world) puts in space the frames fused so
    /// far saw empty, when above [`MAX_SEEN_EMPTY`]; `None` when screening
    /// (a coarse first look, never taken) or below it.
    fn seen_empty(&self, level: usize, pose: &Pose, screening: bool) -> Option<f64> {
        if screening {
            return None;
        }
        let frame = &self.frame.levels[level];
        let share = self
            .free_space
            .share_inside(&frame.points, frame.size().0, pose);
        (share > MAX_SEEN_EMPTY).then_some(share)
    }

    /// The eigen-directions the data are weighed along against the
    /// prediction, at the pose `relative` found from the system `eq`: while
    /// the camera is followed and the view is poorly conditioned, those of
    /// the system that counts a block of [`INFORMATION_BLOCK`] pixels as one
    /// observation, with the map's normals averaged over as many pixels
    /// around ([`block_equations`]). Counted pixel by pixel, a floor with
    /// one small box, orbited, looked pinned along the orbit by the noise of
    /// the map's normals, and the data's noise then led the frames along it
    /// (28 cm off on one noise seed of twelve, nothing reported; 1.4 cm
    /// this way, though another seed still ends 13.5 cm off). Above
    /// [`TrackerConfig::refine_conditioning`] the noise's share (about 1e-4
    /// per inlier) cannot bring a direction near the weak bar, and the
    /// system is taken as it is. So it is after a loss, where a pose is
    /// accepted only with every direction pinned: counted by blocks, a
    /// floor with one small box never is, and the camera would not be
    /// found again there.
    fn weighed_directions(
        &self,
        eq: &Equations,
        relative: &Pose,
        assoc: &Association,
        recovering: bool,
    ) -> Option<Directions> {
        if recovering || eq.conditioning() >= self.config.refine_conditioning {
            return Directions::of(eq);
        }
        let model = &self.model.levels[0];
        let radius = (INFORMATION_BLOCK * model.size().0).div_ceil(self.intrinsics.width as usize);
        let blocks = block_equations(
            &self.frame.levels[0],
            model,
            relative,
            assoc,
            INFORMATION_BLOCK,
            radius,
        );
        Directions::of(&blocks).or_else(|| Directions::of(eq))
    }

    /// What the frame after `found` (the camera found again, or followed
    /// after more frame intervals than the motion model predicts across)
    /// starts from ([`Tracker::start_still`]): the camera walked on by the mean step a
    /// frame since the last good pose, turned no further, if it could make
    /// that step in a frame (the jump bar); else no motion. The turn across
    /// a loss says nothing of the turn to come (the corridor's camera
    /// turned about while it was lost, then walked straight on), and a
    /// camera found after a jump did not move at a constant velocity.
    fn motion_across_loss(&self, found: &Tracked) -> Pose {
        let frames = self.since_good.max(1) as f32;
        let step = (found.pose.translation - self.last_good.translation) / frames;
        if step.length() <= self.config.max_jump {
            Pose::new(glam::Mat3::IDENTITY, found.pose.rotation.transpose() * step)
        } else {
            Pose::IDENTITY
        }
    }

    /// What the motion model learns from a frame found at `found` (fused
    /// or held), before the tracker moves on to it. Followed within the
    /// frame intervals the model predicts across, the velocity is
    /// measured: the motion from the last good pose, one interval's share
    /// of it when the sensor dropped frames in between ([`Pose::root`];
    /// holding the old velocity across such a frame left it stale for as
    /// long as the sensor kept dropping). A camera found by the search
    /// (`searched`) did not move at a constant velocity, nor did one found
    /// after more intervals than the model predicts across: none is
    /// measured, and the next frame's start is guessed from the step
    /// across ([`Tracker::motion_across_loss`]).
    fn learn_motion(&mut self, found: &Tracked, searched: bool) {
        if !searched && (self.velocity_known || self.since_good == 1) {
            let moved = self.last_good.inverse().compose(&found.pose);
            self.velocity = moved.root(self.since_good.max(1));
            self.velocity_known = true;
        } else {
            self.velocity = self.motion_across_loss(found);
            self.velocity_known = false;
        }
    }

    /// Moves the tracker on by an alignment: to the frame's pose when it
    /// was aligned (learning it as a keyframe when it was tracked well),
    /// nowhere when it was lost. `searched`: the result is the search for
    /// a lost camera's, not following's.
    fn conclude(&mut self, result: Tracked, searched: bool) -> Tracked {
        // Fused or lost, the frame ends a streak of held ones.
        self.held_streak = 0;
        self.moved_in.clear();
        let pose = match result.lost {
            None => {
                self.last_conditioning = result.conditioning;
                self.learn_motion(&result, searched);
                // Any frame trusted enough to be fused is a viewpoint to
                // search the map from; a keyframe's pose need not have half
                // its points matched (a frame turning towards unmapped
                // parts has fewer, and those are the views a camera coming
                // back shows again).
                if !searched && result.weak_directions == 0 {
                    self.keyframes
                        .learn(&self.frame.levels[LEVELS - 1].depth, &result.pose);
                }
                self.free_space
                    .add_view(&self.frame.levels[0], &result.pose);
                self.last_good = result.pose;
                self.lost_streak = 0;
                self.since_good = 0;
                result.pose
            }
            Some(_) => {
                self.lost_streak += 1;
                self.velocity_known = false;
                self.last_conditioning = 0.0;
                self.last_good
            }
        };
        Tracked { pose, ..result }
    }
}

#[cfg(test)]
pub(super) mod tests;

#[cfg(test)]
mod recovery_tests;
