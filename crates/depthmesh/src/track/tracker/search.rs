//! The search for a lost camera ([`Tracker::track`]): near its last pose,
//! turned on the spot there or carried round what it looked at, then by
//! global registration against the map's
//! surface ([`crate::track::global_registration`]) and from the keyframes
//! most like the frame ([`crate::track::ferns`]); every candidate is aligned
//! by ICP and verified against the map before it is taken. Also the
//! weighing of a first frame against global registration's poses.

use super::{Search, Tracked, Tracker, LEVELS};
use crate::camera::Pose;
use crate::image::DepthImage;
use crate::map::Mapper;
use crate::track::icp::agreement;
use crate::track::pyramid::half;

/// Frames a lost camera's last motion is extrapolated over, at most (half a
/// second at 30 Hz); beyond that it says little about where the camera is.
pub(super) const MAX_EXTRAPOLATED: usize = 15;

/// Keyframe poses closer than this to one already tried (metres, and the
/// same number in radians) are not tried again in one relocalisation: ICP
/// from either converges to the same pose.
const SAME_CANDIDATE: f32 = 0.05;

/// Candidate poses from global registration refined and verified per
/// relocalisation: the right pose is nearly always among the best few
/// supported, and each costs a model view and an ICP run.
const GLOBAL_CANDIDATES: usize = 3;

/// After a loss the camera is also looked for turned on the spot about the
/// vertical, by multiples of this (degrees) up to half a turn, and the
/// verified pose the map confirms best is taken: a camera swung round
/// faster than ICP can follow is the commonest loss, and global
/// registration alone finds such a frame wherever the map looks alike (a
/// corridor's bays: 6 m off). From 30° apart, ICP from the nearest turn
/// (10° off, 40 cm at the wall) traded the turn for a slide along the
/// corridor and was verified 56 cm off; from 10° apart, turns of 70° and
/// 76° were found within 0.9 cm.
const TURN_STEP_DEGREES: f32 = 10.0;

/// Frames after the one where the camera was lost that it is still looked
/// for turned on the spot, as in that one (see [`TURN_STEP_DEGREES`]): each
/// look costs tens of model views, and a camera lost longer may be
/// anywhere.
const TURN_FRAMES: usize = 2;

/// Turns of the search on the spot (see [`TURN_STEP_DEGREES`]) refined and
/// verified in full. Every turn is first screened by ICP on the coarsest
/// frame level against a view at half the model's resolution; those at
/// whose pose the map explains the largest share of the frame go on. The
/// share contradicted does not count there: at that resolution a right
/// pose can have as much of the frame off the map's surface as a wrong
/// one (a corridor's turn about: 41–50 % at the right pose, which the full
/// verification accepts).
const TURNS_REFINED: usize = 3;

/// After a loss the camera is also looked for carried round what it
/// looked at, about the vertical through the point that far ahead on its
/// axis ([`Axes::ahead`]), by multiples of this (degrees) either way, up
/// to the first that carries it [`ORBIT_CARRY`]: someone scanning an
/// object or a table walks round it, and a camera carried 0.5–1 m round it
/// between two frames (10–20° at 3 m) lands where neither the turns on the
/// spot nor the map's features found it (the chairs: lost for up to 26
/// frames while the camera went on round).
const ORBIT_STEP_DEGREES: f32 = 10.0;

/// How far the camera is looked for carried round (metres, the chord):
/// the jumps a camera is to be found again after. Further round, a
/// repeating view offers look-alike places: carried up to 60° round a
/// point 2 m ahead, a camera turned about in a corridor of bays alike was
/// verified 3 m along it.
const ORBIT_CARRY: f32 = 1.0;

/// How many of the poses carried round one point ([`ORBIT_STEP_DEGREES`])
/// are refined after screening: all of them for a point 2 m or more ahead (at
/// most 10°, 20° and 30° either way). Screened, the table seen from every
/// side overlaps its view alike (0.62–0.63 for four of six), and with the
/// best three refined three of the six carried jumps of the table were
/// not found there; with six, they are.
const ORBITS_REFINED: usize = 6;

/// The camera is also looked for carried round the point this many times
/// as far ahead as the one it looked at (see [`ORBIT_STEP_DEGREES`]).
const ORBIT_FAR_PIVOT: f32 = 2.0;

/// What the search turns a lost camera about, from the map's view from its
/// last good pose (camera axes).
#[derive(Clone, Copy, Debug)]
pub(super) struct Axes {
    /// The vertical ([`vertical`]).
    up: glam::Vec3,
    /// How far ahead the camera looked: the median depth of the middle
    /// ninth of the view, if it has any.
    ahead: Option<f32>,
}

/// The median depth of the middle ninth of `view`, if any is measured.
fn ahead(view: &crate::track::pyramid::Level) -> Option<f32> {
    let (w, h) = view.size();
    let mut depths: Vec<f32> = (h / 3..2 * h / 3)
        .flat_map(|v| (w / 3..2 * w / 3).map(move |u| v * w + u))
        .map(|i| view.depth.data[i])
        .filter(|&d| d > 0.0)
        .collect();
    if depths.is_empty() {
        return None;
    }
    let middle = depths.len() / 2;
    Some(*depths.select_nth_unstable_by(middle, f32::total_cmp).1)
}

/// The vertical in a view's camera axes, from the view's `normals`: the
/// mean of those facing within 45° of the image's up (a floor, a table top)
/// when they are a tenth of the normals, else the image's up. A camera
/// pitched down at a floor turns about the floor's normal, not about its
/// own axis: turned about that, a camera pitched 22° comes at best 25° from
/// a 70° turn, beyond ICP's reach.
fn vertical(normals: &[glam::Vec3]) -> glam::Vec3 {
    let image_up = glam::Vec3::NEG_Y;
    let (mut sum, mut facing, mut seen) = (glam::Vec3::ZERO, 0usize, 0usize);
    for &n in normals {
        if n == glam::Vec3::ZERO {
            continue;
        }
        seen += 1;
        if n.dot(image_up) > std::f32::consts::FRAC_1_SQRT_2 {
            sum += n;
            facing += 1;
        }
    }
    if facing * 10 < seen || sum == glam::Vec3::ZERO {
        image_up
    } else {
        sum.normalize()
    }
}

impl Tracker {
    /// The first step of the search for a lost camera ([`Tracker::track`]),
    /// in the frame `lost_streak + 1` frames from the last good pose: the
    /// frame near its last pose ([`Tracker::recover_near`]), and the
    /// vertical of the map's view from there, which the search's turns are
    /// about.
    pub(super) fn look_near(&mut self, map: &dyn Mapper) -> (Tracked, Axes) {
        let near = self.recover_near(map);
        // The model pyramid holds the view from the last good pose that
        // `recover_near` built.
        let view = &self.model.levels[0];
        let axes = Axes {
            up: vertical(&view.normals),
            ahead: ahead(view),
        };
        (near, axes)
    }

    /// The rest of the search after [`Tracker::look_near`] found `near`:
    /// turned on the spot and carried round what it looked at, about
    /// `axes`, then relocalised.
    pub(super) fn search_on(&mut self, map: &dyn Mapper, near: Tracked, axes: Axes) -> Tracked {
        let mut result = near;
        if result.lost.is_some() && self.lost_streak <= TURN_FRAMES {
            let before = result.iterations;
            result = self.recover_turned(axes, map);
            result.iterations += before;
        }
        if result.lost.is_some() {
            let before = result.iterations;
            result = self.relocalise_prepared(map);
            result.iterations += before;
        }
        result
    }

    /// Finds `depth`'s pose in `map` from the keyframes alone, with no
    /// prior pose; the tracking state is unchanged. Lost when no candidate
    /// passes verification.
    pub fn relocalise(&mut self, depth: &DepthImage, map: &dyn Mapper) -> Tracked {
        self.prepare(depth);
        self.relocalise_prepared(map)
    }

    /// `near`, unless `other` is aligned and `near` is lost, or `other`
    /// lies farther from it than the verification distance and the map's
    /// view confirms more of the frame's points there, less those it
    /// contradicts; with the iterations of both. Nearer, both confirm the
    /// same points, and which scores higher is noise (a table's first
    /// frame: 0.1 mm off and 6.7 mm off, the second scoring 0.3 % higher).
    pub(super) fn better_of(&mut self, map: &dyn Mapper, near: Tracked, other: Tracked) -> Tracked {
        let iterations = near.iterations + other.iterations;
        let take_other = other.lost.is_none()
            && match near.lost {
                Some(_) => true,
                None => {
                    let apart = near.pose.inverse().compose(&other.pose);
                    let turned = f64::from(apart.rotation_angle()) * near.range;
                    f64::from(apart.translation.length()).max(turned)
                        > f64::from(self.config.verify_distance)
                        && self.confirmed(map, &other.pose) > self.confirmed(map, &near.pose)
                }
            };
        // A pose found from a candidate is the frame's own here, not a
        // relocalisation.
        let chosen = if take_other {
            Tracked {
                relocalised: false,
                ..other
            }
        } else {
            near
        };
        Tracked {
            iterations,
            ..chosen
        }
    }

    /// Without a measured motion ICP starts from no motion, and along what
    /// the view pins only at its edges (a sofa seen from the front, the
    /// camera moving along it) it can settle centimetres off (5 cm in the
    /// first frame of such a scene, taken on by the velocity and then by
    /// the map); global registration against the map proposes other
    /// starts. `near` (ICP from no motion) is kept unless the verified pose
    /// found from them is better ([`Tracker::better_of`]).
    pub(super) fn start_globally(&mut self, map: &dyn Mapper, near: Tracked) -> Tracked {
        let global = self.global_candidates(map);
        let found = self.relocalise_from(&global, &mut Vec::new(), false, map);
        self.better_of(map, near, found)
    }

    /// The share of the frame's points the map's view from `pose` confirms
    /// less the share it contradicts (see [`agreement`]).
    fn confirmed(&mut self, map: &dyn Mapper, pose: &Pose) -> f64 {
        let model = map.render_depth(&self.model_intrinsics, pose);
        if !self.model_view(&model, self.model_intrinsics) {
            return f64::NEG_INFINITY;
        }
        let agree = agreement(
            &self.frame.levels[1],
            &self.model.levels[0],
            &Pose::IDENTITY,
            self.config.verify_distance,
        );
        agree.overlap - agree.contradicted
    }

    /// After a loss: the frame against the map's view from the last good
    /// pose.
    fn recover_near(&mut self, map: &dyn Mapper) -> Tracked {
        let model = map.render_depth(&self.model_intrinsics, &self.last_good);
        if !self.model_view(&model, self.model_intrinsics) {
            return Tracked::empty(self.last_good);
        }
        self.search_near()
    }

    /// After a loss, when the camera is not found near its last pose: the
    /// camera turned on the spot about the vertical `axes.up` (in its axes
    /// at the last good pose; see [`vertical`]) by each multiple of
    /// [`TURN_STEP_DEGREES`], screened coarsely, the best [`TURNS_REFINED`]
    /// refined: the verified pose the map confirms best; if none is
    /// verified, the same for the camera carried round the point
    /// `axes.ahead` in front of it, and round the point
    /// [`ORBIT_FAR_PIVOT`] times as far, by each multiple of
    /// [`ORBIT_STEP_DEGREES`], the best [`ORBITS_REFINED`] about each
    /// refined.
    fn recover_turned(&mut self, axes: Axes, map: &dyn Mapper) -> Tracked {
        let steps = (180.0 / TURN_STEP_DEGREES).round() as usize;
        // About the vertical through `centre` (camera axes), by `turn`.
        let last_good = self.last_good;
        let turned = |centre: glam::Vec3, turn: f32| {
            let q = glam::Quat::from_axis_angle(axes.up, turn);
            last_good.compose(&Pose::from_quat(q, centre - q * centre))
        };
        let spins: Vec<Pose> = (1..=steps)
            .flat_map(|i| {
                let turn = (i as f32 * TURN_STEP_DEGREES).to_radians();
                // Half a turn either way is the same pose.
                [turn, -turn]
                    .into_iter()
                    .take(if i == steps { 1 } else { 2 })
            })
            .map(|turn| turned(glam::Vec3::ZERO, turn))
            .collect();
        let spun = self.screen_and_refine(&[(&spins, TURNS_REFINED)], map);
        let Some(ahead) = axes.ahead.filter(|_| spun.lost.is_some()) else {
            return spun;
        };
        // Only when no turn on the spot explains the frame: where the view
        // repeats (a corridor's bays alike every 3 m), a pose carried round
        // a point 2 m ahead explained a turned camera's frame as well as
        // its own turn, 3 m along the corridor.
        //
        // What the camera looked at may not be what it is carried round:
        // the middle of its view can be a sofa 1.3 m ahead while the camera
        // walks round the room's middle beyond it (the sofa room carried
        // 0.5–1 m round: every pose about the sofa contradicted, the camera
        // lost for 18 and 23 frames). The poses about a point twice as far
        // are screened apart and refined as many: ranked together, a table
        // seen from every side screens alike from both, and the right pose
        // was left out for its mirror image across the table.
        let step = ORBIT_STEP_DEGREES.to_radians();
        let orbits = [ahead, ORBIT_FAR_PIVOT * ahead].map(|pivot| {
            let centre = glam::Vec3::Z * pivot;
            // Up to the first turn that carries the camera the whole way.
            let carried_by = |turn: f32| 2.0 * pivot * (turn / 2.0).sin();
            let turns = (1..).map(|i| i as f32 * step).take_while(|&turn| {
                turn <= std::f32::consts::PI && carried_by(turn - step) < ORBIT_CARRY
            });
            turns
                .flat_map(|turn| [turn, -turn])
                .map(|turn| turned(centre, turn))
                .collect::<Vec<Pose>>()
        });
        let mut carried = self.screen_and_refine(
            &[(&orbits[0], ORBITS_REFINED), (&orbits[1], ORBITS_REFINED)],
            map,
        );
        carried.iterations += spun.iterations;
        carried
    }

    /// Each group of candidates screened by ICP on the coarsest frame level
    /// against a view at half the model's resolution, apart from the other
    /// groups, and its best (as many as the group says) kept; those kept
    /// refined together: the verified pose the map confirms best.
    fn screen_and_refine(&mut self, groups: &[(&[Pose], usize)], map: &dyn Mapper) -> Tracked {
        let mut best = Vec::new();
        let mut iterations = 0;
        for &(candidates, kept) in groups {
            let (screened, screening) = self.screen(candidates, kept, map);
            best.extend(screened);
            iterations += screening;
        }
        let mut result = self.relocalise_from(&best, &mut Vec::new(), false, map);
        result.iterations += iterations;
        result
    }

    /// The poses ICP on the coarsest frame level, against a view at half
    /// the model's resolution, brings the best `kept` of `candidates` to
    /// (by the share of the frame the map explains there), and the
    /// iterations it took.
    fn screen(&mut self, candidates: &[Pose], kept: usize, map: &dyn Mapper) -> (Vec<Pose>, usize) {
        // Most candidates face what the frame does not show; rendering and
        // aligning each in full cost 0.56–0.68 s on a 640×480 frame.
        let screen = half(&self.model_intrinsics);
        let mut iterations = 0;
        let mut screened: Vec<(f64, Pose)> = Vec::with_capacity(candidates.len());
        for &pose in candidates {
            let model = map.render_depth(&screen, &pose);
            if !self.model_view(&model, screen) {
                continue;
            }
            let (t, agree) = self.align(pose, Pose::IDENTITY, Search::Screen);
            iterations += t.iterations;
            screened.push((agree.overlap, t.pose));
        }
        screened.sort_by(|a, b| b.0.total_cmp(&a.0));
        (
            screened.iter().take(kept).map(|s| s.1).collect(),
            iterations,
        )
    }

    /// ICP against the model view from the last good pose (built) after a
    /// loss: first where the last motion would have taken the camera, then
    /// at the last good pose.
    pub(super) fn search_near(&self) -> Tracked {
        let frames = self.since_good.clamp(1, MAX_EXTRAPOLATED);
        let extrapolated = self.velocity.power(frames);
        let moving = self.icp(self.last_good, extrapolated, Search::Recover);
        if moving.lost.is_none() {
            return moving;
        }
        let mut still = self.icp(self.last_good, Pose::IDENTITY, Search::Recover);
        still.iterations += moving.iterations;
        still
    }

    /// Describes the map's surface as seen from the keyframes (from the
    /// start before the first is learnt), unless it was described from
    /// them already, for relocalisation by global registration
    /// ([`crate::track::global_registration`]). Relocalising does this itself when
    /// needed; calling it first keeps that work out of the first attempt.
    pub fn describe_map(&mut self, map: &dyn Mapper) {
        let (_, poses) = self.keyframes.saved();
        // Before the first keyframe, the map is what the start saw.
        let start = [self.last_good];
        let poses = if poses.is_empty() { &start[..] } else { poses };
        self.map_features.update(map, poses, &self.model_intrinsics);
    }

    /// Candidate poses of the prepared frame by global registration against
    /// the map's described surface, best supported first.
    fn global_candidates(&mut self, map: &dyn Mapper) -> Vec<Pose> {
        self.describe_map(map);
        // The coarsest frame level at least as wide as the model view: the
        // map's points were seen at that resolution.
        let level = (0..LEVELS)
            .rev()
            .find(|&l| self.frame.levels[l].size().0 >= self.model_intrinsics.width as usize)
            .unwrap_or(0);
        self.registration
            .candidates(
                &self.frame.levels[level],
                &self.map_features,
                GLOBAL_CANDIDATES,
            )
            .iter()
            .map(|c| c.pose)
            .collect()
    }

    /// Relocalises the prepared frame: first by global registration
    /// against the map's described surface, which needs no keyframe near
    /// the camera, then, if no candidate from it is verified, from the
    /// keyframes most like the frame.
    fn relocalise_prepared(&mut self, map: &dyn Mapper) -> Tracked {
        let global = self.global_candidates(map);
        let mut tried =
            Vec::with_capacity(GLOBAL_CANDIDATES + self.config.relocalisation.candidates);
        // Candidates come best supported first, and the first one verified
        // is taken: verification, not the ranking, guards against a wrong
        // pose, and each further candidate costs a model view and ICP.
        let found = self.relocalise_from(&global, &mut tried, true, map);
        if found.lost.is_none() {
            return found;
        }
        let keyframes: Vec<Pose> = self
            .keyframes
            .nearest(&self.frame.levels[LEVELS - 1].depth)
            .into_iter()
            .map(|(pose, _)| pose)
            .collect();
        let mut result = self.relocalise_from(&keyframes, &mut tried, false, map);
        result.iterations += found.iterations;
        if result.lost.is_some() && result.iterations == found.iterations {
            // Nothing new was tried: the first failure is the global one's.
            return Tracked {
                iterations: result.iterations,
                ..found
            };
        }
        result
    }

    /// ICP from each of `candidates` not within [`SAME_CANDIDATE`] of one
    /// in `tried` (which they join), each against the map's view from that
    /// pose; the verified result whose points the map's surface, seen from
    /// the pose found, confirms most, less those it contradicts (the first
    /// verified one if `first`), or the first failure. Not the overlap
    /// alone: a pose may be verified with a third of the frame on the map,
    /// and a wrong one that puts more of it on the map's surface, much of it
    /// off, must not win.
    ///
    /// Not scored against the view ICP started from either: ICP can carry
    /// a candidate a metre from it, and that view then covers only part of
    /// what the frame sees from where it ended. In the simulated bunnies
    /// scene (three alike bunnies 1.5 m apart; `bench/track_sim_jumps.sh`,
    /// frames 100–103 left out) ICP brought one of the turns on the spot at
    /// the last pose to the camera, 1.34 m away: 0.74 against the turn's
    /// view, 0.95 against its own. It lost to a place 1.5 m off the camera
    /// (0.84), where the frame was taken and every frame after it followed.
    pub(super) fn relocalise_from(
        &mut self,
        candidates: &[Pose],
        tried: &mut Vec<Pose>,
        first: bool,
        map: &dyn Mapper,
    ) -> Tracked {
        let mut verified: Vec<Tracked> = Vec::new();
        let mut first_failure = Tracked::empty(self.last_good);
        let mut iterations = 0;
        for &pose in candidates {
            let seen = tried.iter().any(|p| {
                let d = p.inverse().compose(&pose);
                d.translation.length() < SAME_CANDIDATE && d.rotation_angle() < SAME_CANDIDATE
            });
            if seen {
                continue;
            }
            tried.push(pose);
            let model = map.render_depth(&self.model_intrinsics, &pose);
            if !self.model_view(&model, self.model_intrinsics) {
                continue;
            }
            let t = self.icp(pose, Pose::IDENTITY, Search::Relocalise);
            iterations += t.iterations;
            match t.lost {
                None => {
                    verified.push(t);
                    if first {
                        break;
                    }
                }
                Some(_) if first_failure.iterations == 0 => first_failure = t,
                Some(_) => {}
            }
        }
        // Scoring renders the map's view from each pose found: only worth
        // it when there is a choice.
        let best = if verified.len() > 1 {
            let mut best: Option<(f64, Tracked)> = None;
            for t in verified {
                let score = self.confirmed(map, &t.pose);
                if best.as_ref().is_none_or(|(s, _)| score > *s) {
                    best = Some((score, t));
                }
            }
            best.map(|(_, t)| t)
        } else {
            verified.pop()
        };
        let mut result = match best {
            Some(t) => Tracked {
                relocalised: true,
                ..t
            },
            None => Tracked {
                pose: self.last_good,
                ..first_failure
            },
        };
        result.iterations = iterations;
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    // A camera pitched 22° down at a floor, with a wall ahead: the turn
    // axis is the floor's normal; with only the wall, the image's up.
    #[test]
    fn the_vertical_is_the_floor_normal_when_the_view_has_a_floor() {
        let pitch = 22f32.to_radians();
        let floor = Vec3::new(0.0, -pitch.cos(), -pitch.sin());
        let wall = Vec3::new(0.3, 0.0, -1.0).normalize();
        let mut normals = vec![floor; 30];
        normals.extend([wall; 60]);
        normals.extend([Vec3::ZERO; 10]);
        assert!(vertical(&normals).angle_between(floor) < 1e-5);
        normals.truncate(2);
        normals.extend([wall; 60]);
        assert_eq!(vertical(&normals), Vec3::NEG_Y);
    }
}
