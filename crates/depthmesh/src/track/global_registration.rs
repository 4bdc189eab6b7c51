//! Global registration for relocalisation: a lost frame is matched to the
//! map's surface by local shape alone, with no prior pose and no nearby
//! keyframe (Rusu, Blodow and Beetz 2009, "Fast Point Feature Histograms
//! (FPFH) for 3D registration", with RANSAC over three correspondences as
//! in Open3D's global registration).
//!
//! ICP converges only from a few centimetres and degrees; a camera that
//! reappears 10–50 cm and 15–40° from every keyframe is outside that basin.
//! Local shape does not depend on where it is seen from: the frame's points
//! and the map's, each thinned to one oriented point per
//! [`VOXEL`]-sized cell, are described by histograms of the angles between
//! their normals and those of their neighbours within [`FEATURE_RADIUS`];
//! each frame point is matched to the map point with the most similar
//! histogram, and rigid motions fitted to three matches at a time are
//! scored by how many matches they bring together. The best few poses are
//! only candidates: the tracker refines each by ICP against the map's view
//! and verifies it there before anything is accepted.
//!
//! The map's points come from the map itself, seen from the keyframes'
//! poses ([`MapFeatures::update`]): any back-end that renders depth can be
//! searched, and the points are as good as the fused surface. Memory is
//! bounded by [`MAX_MAP_CELLS`]; the cells are kept, so a keyframe learnt
//! later adds its view without the others being seen again.

use super::pyramid::{Level, Pyramid};
use crate::camera::{Intrinsics, Pose};
use crate::linalg::horn;
use crate::map::Mapper;
use glam::Vec3;
use rand::rngs::SmallRng;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use std::collections::HashMap;

/// Side of the cells points are thinned to (metres). Open3D's global
/// registration uses 5 cm for rooms: small enough for a cupboard's edge or
/// a kettle, large enough that a frame has a few hundred to a few thousand
/// points, which keeps matching in the tens of milliseconds.
pub const VOXEL: f32 = 0.05;

/// Neighbours within this describe a point (metres): five cells, the ratio
/// Rusu et al. and Open3D use; enough neighbours (tens) for the histogram
/// to be stable, small enough to lie mostly inside one view.
pub const FEATURE_RADIUS: f32 = 5.0 * VOXEL;

/// Bins per angle of the histogram (Rusu et al.'s 11).
const BINS: usize = 11;

/// Length of a descriptor: three angles' histograms.
pub const FEATURE_LEN: usize = 3 * BINS;

/// One descriptor.
pub type Feature = [f32; FEATURE_LEN];

/// Points with fewer neighbours than this are not matched: their
/// histograms are mostly noise (a lone speck, a frame's corner).
const MIN_NEIGHBOURS: u32 = 8;

/// A cell whose averaged normal is shorter than this (the cell's normals
/// disagree: a thin board seen from both sides, a corner) has no normal.
const MIN_NORMAL_AGREEMENT: f32 = 0.5;

/// A match moved within this of its map point supports a pose (metres):
/// 1.5 cells, Open3D's choice; the cells' centroids differ by up to about
/// a cell between two views.
const INLIER_DISTANCE: f32 = 1.5 * VOXEL;

/// Three matches are fitted only if the sides of their triangles in the
/// frame and in the map agree to this ratio (a rigid motion keeps lengths;
/// Open3D's edge-length checker uses 0.9) …
const EDGE_RATIO: f32 = 0.9;

/// … and every side is at least this long (metres): a smaller triangle
/// fixes the rotation poorly.
const MIN_EDGE: f32 = 3.0 * VOXEL;

/// … and the fitted rotation turns each frame normal to within this angle's
/// cosine of its map normal (45°): both face their cameras.
const MIN_NORMAL_COS: f32 = std::f32::consts::FRAC_1_SQRT_2;

/// Triangles of matches drawn. Most fail the length test in a few
/// nanoseconds; with a tenth of the matches right, a correct triangle is
/// drawn about 20 times in 20 000.
const SAMPLES: usize = 20_000;

/// A pose needs this many supporting matches to be a candidate: three are
/// any triangle's own.
const MIN_SUPPORT: usize = 8;

/// Candidates closer than this (metres, and the same in radians) are one.
const DISTINCT: f32 = 0.1;

/// Cells of the map kept at most (≈ 200 bytes each with the descriptor:
/// 40 MB); once full, new views add nothing, as with the keyframes.
pub const MAX_MAP_CELLS: usize = 200_000;

/// The seed of the samples: the same candidates in every run.
const SEED: u64 = 0x0d3e_97f4_5eed_0002;

/// Sums of one cell's points and normals.
#[derive(Clone, Copy, Debug, Default)]
struct Cell {
    point: Vec3,
    normal: Vec3,
    count: u32,
}

/// Oriented points, one per occupied cell, with their descriptors.
#[derive(Clone, Debug, Default)]
pub struct Cloud {
    /// Cell centroids.
    pub points: Vec<Vec3>,
    /// Unit normals, facing the camera that saw them.
    pub normals: Vec<Vec3>,
    /// FPFH descriptors, each angle's histogram summing to 200.
    pub features: Vec<Feature>,
    /// Neighbours within [`FEATURE_RADIUS`] of each point.
    pub neighbours: Vec<u32>,
    /// Scratch: points ordered by their neighbour-search cell, and where
    /// each such cell's run starts and ends.
    order: Vec<(u64, u32)>,
    runs: HashMap<u64, (u32, u32)>,
    spfh: Vec<Feature>,
}

/// The cell of `p` for cells of side `size`, packed into one key (21 bits
/// an axis: ±50 km at 5 cm).
fn cell_key(p: Vec3, size: f32) -> u64 {
    let c = (p / size).floor();
    let pack = |v: f32| ((v as i64 + (1 << 20)) as u64) & 0x1f_ffff;
    pack(c.x) << 42 | pack(c.y) << 21 | pack(c.z)
}

/// The key of the cell `d` cells from `key` along each axis.
fn offset_key(key: u64, d: [i64; 3]) -> u64 {
    let axis = |shift: u32, d: i64| (((key >> shift) & 0x1f_ffff) as i64 + d) as u64 & 0x1f_ffff;
    axis(42, d[0]) << 42 | axis(21, d[1]) << 21 | axis(0, d[2])
}

/// Adds the points of `level` that have a normal, moved by `pose`, to
/// `cells`, unless that would make more than `max_cells` cells.
fn accumulate(level: &Level, pose: &Pose, cells: &mut HashMap<u64, Cell>, max_cells: usize) {
    for (p, n) in level.points.iter().zip(&level.normals) {
        if *n == Vec3::ZERO {
            continue;
        }
        let p = pose.transform_point(*p);
        let key = cell_key(p, VOXEL);
        if cells.len() >= max_cells && !cells.contains_key(&key) {
            continue;
        }
        let c = cells.entry(key).or_default();
        c.point += p;
        c.normal += pose.transform_vector(*n);
        c.count += 1;
    }
}

impl Cloud {
    /// Rebuilds the cloud from `cells`, in the order of their keys (the
    /// hash map's order changes from run to run; the samples must not).
    fn build(&mut self, cells: &HashMap<u64, Cell>) {
        self.order.clear();
        self.order.extend(cells.keys().map(|&k| (k, 0)));
        self.order.sort_unstable();
        self.points.clear();
        self.normals.clear();
        for (key, _) in &self.order {
            let c = cells[key];
            let n = c.normal / c.count as f32;
            if n.length() >= MIN_NORMAL_AGREEMENT {
                self.points.push(c.point / c.count as f32);
                self.normals.push(n.normalize());
            }
        }
        self.describe();
    }

    /// Computes every point's FPFH descriptor: first each point's own
    /// histogram of pair angles with its neighbours (SPFH), then the
    /// descriptor as that plus the neighbours' own, weighted by inverse
    /// squared distance (Open3D's form).
    fn describe(&mut self) {
        let n = self.points.len();
        // Neighbour search on cells of the feature radius: 27 cells hold
        // every neighbour.
        self.order.clear();
        self.order.extend(
            self.points
                .iter()
                .enumerate()
                .map(|(i, p)| (cell_key(*p, FEATURE_RADIUS), i as u32)),
        );
        self.order.sort_unstable();
        self.runs.clear();
        let mut start = 0;
        for i in 1..=n {
            if i == n || self.order[i].0 != self.order[start].0 {
                self.runs
                    .insert(self.order[start].0, (start as u32, i as u32));
                start = i;
            }
        }
        let search = Neighbours {
            points: &self.points,
            order: &self.order,
            runs: &self.runs,
        };
        let normals = &self.normals;
        self.spfh.resize(n, [0.0; FEATURE_LEN]);
        self.neighbours.resize(n, 0);
        self.spfh
            .par_iter_mut()
            .zip(self.neighbours.par_iter_mut())
            .enumerate()
            .for_each(|(i, (h, count))| {
                *h = [0.0; FEATURE_LEN];
                let mut k = 0u32;
                search.each(i, |j, _| {
                    if let Some(f) =
                        pair_features(search.points[i], normals[i], search.points[j], normals[j])
                    {
                        add(h, &f, 1.0);
                        k += 1;
                    }
                });
                if k > 0 {
                    h.iter_mut().for_each(|v| *v *= 100.0 / k as f32);
                }
                *count = k;
            });
        let spfh = &self.spfh;
        self.features.resize(n, [0.0; FEATURE_LEN]);
        self.features.par_iter_mut().enumerate().for_each(|(i, f)| {
            *f = [0.0; FEATURE_LEN];
            search.each(i, |j, d2| {
                if d2 > 0.0 {
                    for (v, s) in f.iter_mut().zip(&spfh[j]) {
                        *v += s / d2;
                    }
                }
            });
            for block in f.chunks_exact_mut(BINS) {
                let sum: f32 = block.iter().sum();
                if sum > 0.0 {
                    block.iter_mut().for_each(|v| *v *= 100.0 / sum);
                }
            }
            for (v, s) in f.iter_mut().zip(&spfh[i]) {
                *v += s;
            }
        });
    }
}

/// Radius search over a [`Cloud`]'s points.
struct Neighbours<'a> {
    points: &'a [Vec3],
    order: &'a [(u64, u32)],
    runs: &'a HashMap<u64, (u32, u32)>,
}

impl Neighbours<'_> {
    /// Calls `f(j, squared distance)` for every other point within
    /// [`FEATURE_RADIUS`] of point `i`.
    fn each(&self, i: usize, mut f: impl FnMut(usize, f32)) {
        let p = self.points[i];
        let key = cell_key(p, FEATURE_RADIUS);
        let r2 = FEATURE_RADIUS * FEATURE_RADIUS;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(&(a, b)) = self.runs.get(&offset_key(key, [dx, dy, dz])) else {
                        continue;
                    };
                    for &(_, j) in &self.order[a as usize..b as usize] {
                        let j = j as usize;
                        let d2 = self.points[j].distance_squared(p);
                        if j != i && d2 <= r2 {
                            f(j, d2);
                        }
                    }
                }
            }
        }
    }
}

/// Adds the bins of the pair features `f` to the histogram `h`.
fn add(h: &mut Feature, f: &[f32; 3], weight: f32) {
    let bin = |v: f32| ((v * BINS as f32) as usize).min(BINS - 1);
    // α (an angle in −π..π), φ and θ's cosines (−1..1), each as 0..1.
    h[bin((f[0] + std::f32::consts::PI) / std::f32::consts::TAU)] += weight;
    h[BINS + bin((f[1] + 1.0) * 0.5)] += weight;
    h[2 * BINS + bin((f[2] + 1.0) * 0.5)] += weight;
}

/// The three angles of a point pair in the Darboux frame of the point
/// whose normal is closer to the line between them (Rusu et al., as in
/// Open3D's `ComputePairFeatures`); `None` when the frame is undefined.
fn pair_features(p1: Vec3, n1: Vec3, p2: Vec3, n2: Vec3) -> Option<[f32; 3]> {
    let d = p2 - p1;
    let len = d.length();
    if len == 0.0 {
        return None;
    }
    let a1 = n1.dot(d) / len;
    let a2 = n2.dot(d) / len;
    let (u, n_other, d, theta) = if a1.abs().acos() > a2.abs().acos() {
        (n2, n1, -d, -a2)
    } else {
        (n1, n2, d, a1)
    };
    let v = d.cross(u);
    let v_len = v.length();
    if v_len == 0.0 {
        return None;
    }
    let v = v / v_len;
    let w = u.cross(v);
    Some([w.dot(n_other).atan2(u.dot(n_other)), v.dot(n_other), theta])
}

/// The rigid motion taking the points `from` onto `to` in the least-squares
/// sense ([`horn`]); `None` for fewer than three pairs.
fn rigid_fit(pairs: impl Iterator<Item = (Vec3, Vec3)> + Clone) -> Option<Pose> {
    pairs.clone().nth(2)?;
    let (rotation, t) = horn(pairs.map(|(f, t)| (f.as_dvec3(), t.as_dvec3())));
    let pose = Pose::new(rotation.as_mat3(), t.as_vec3());
    pose.translation.is_finite().then_some(pose)
}

/// The map's surface as described points, grown view by view.
#[derive(Clone, Debug, Default)]
pub struct MapFeatures {
    cells: HashMap<u64, Cell>,
    /// Keyframes whose views are in `cells`.
    views: usize,
    /// Whether `cloud` is older than `cells`.
    stale: bool,
    cloud: Cloud,
    /// The described points' descriptors, for nearest-neighbour search.
    tree: FeatureTree,
    view: Pyramid,
}

impl MapFeatures {
    /// Adds the map's views from the keyframe poses not seen yet (`poses`
    /// grows at the end; a shorter list starts over), rendered with `k`,
    /// and describes the cloud again if it changed.
    pub fn update(&mut self, map: &dyn Mapper, poses: &[Pose], k: &Intrinsics) {
        if poses.len() < self.views {
            *self = MapFeatures::default();
        }
        for pose in &poses[self.views..] {
            let depth = map.render_depth(k, pose);
            self.view.build(&depth, k, 1);
            accumulate(&self.view.levels[0], pose, &mut self.cells, MAX_MAP_CELLS);
            self.stale = true;
        }
        self.views = poses.len();
        if self.stale {
            self.cloud.build(&self.cells);
            self.tree.build(&self.cloud);
            self.stale = false;
        }
    }

    /// Forgets every view (the map was replaced).
    pub fn clear(&mut self) {
        *self = MapFeatures::default();
    }

    /// The described points of the map.
    pub fn cloud(&self) -> &Cloud {
        &self.cloud
    }
}

/// Matches a frame to [`MapFeatures`]; its buffers are reused.
#[derive(Clone, Debug, Default)]
pub struct GlobalRegistration {
    cells: HashMap<u64, Cell>,
    frame: Cloud,
    /// For each frame point that is matched, its map point.
    matches: Vec<(u32, u32)>,
}

/// One candidate pose and the matches that support it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Candidate {
    /// Camera-to-world.
    pub pose: Pose,
    /// Matches within [`INLIER_DISTANCE`] at that pose.
    pub support: usize,
}

impl GlobalRegistration {
    /// Up to `count` distinct candidate poses (camera-to-world) of the
    /// frame whose camera-space points and normals are `level`, best
    /// supported first; empty when nothing in the map is like the frame.
    pub fn candidates(&mut self, level: &Level, map: &MapFeatures, count: usize) -> Vec<Candidate> {
        let target = &map.cloud;
        if target.points.is_empty() || count == 0 {
            return Vec::new();
        }
        self.cells.clear();
        accumulate(level, &Pose::IDENTITY, &mut self.cells, usize::MAX);
        self.frame.build(&self.cells);
        let frame = &self.frame;
        // Each described frame point's nearest map descriptor.
        self.matches.clear();
        // Parallel collection keeps the order: the samples are repeatable.
        let tree = &map.tree;
        self.matches.par_extend(
            (0..frame.points.len())
                .into_par_iter()
                .filter(|&i| frame.neighbours[i] >= MIN_NEIGHBOURS)
                .filter_map(|i| {
                    tree.nearest(&target.features, &frame.features[i])
                        .map(|j| (i as u32, j))
                }),
        );
        self.ransac(target, count)
    }

    /// Fits rigid motions to random triangles of matches and keeps the
    /// `count` best supported distinct ones, each refitted to its support.
    fn ransac(&self, target: &Cloud, count: usize) -> Vec<Candidate> {
        let m = &self.matches;
        if m.len() < MIN_SUPPORT {
            return Vec::new();
        }
        let frame = &self.frame;
        let from = |k: usize| frame.points[m[k].0 as usize];
        let to = |k: usize| target.points[m[k].1 as usize];
        let support = |pose: &Pose| {
            (0..m.len())
                .filter(|&k| {
                    pose.transform_point(from(k)).distance_squared(to(k))
                        <= INLIER_DISTANCE * INLIER_DISTANCE
                })
                .count()
        };
        let mut rng = SmallRng::seed_from_u64(SEED);
        let mut best: Vec<Candidate> = Vec::with_capacity(count + 1);
        for _ in 0..SAMPLES {
            let k = [0; 3].map(|_| rng.gen_range(0..m.len()));
            let sides_agree = (0..3).all(|s| {
                let (a, b) = (k[s], k[(s + 1) % 3]);
                let lf = from(a).distance(from(b));
                let lt = to(a).distance(to(b));
                lf >= MIN_EDGE && lt >= MIN_EDGE && lf.min(lt) >= EDGE_RATIO * lf.max(lt)
            });
            if !sides_agree {
                continue;
            }
            let Some(pose) = rigid_fit(k.iter().map(|&k| (from(k), to(k)))) else {
                continue;
            };
            let normals_agree = k.iter().all(|&k| {
                let (i, j) = (m[k].0 as usize, m[k].1 as usize);
                pose.transform_vector(frame.normals[i])
                    .dot(target.normals[j])
                    >= MIN_NORMAL_COS
            });
            if !normals_agree {
                continue;
            }
            let s = support(&pose);
            if s >= MIN_SUPPORT {
                keep(&mut best, Candidate { pose, support: s }, count);
            }
        }
        // Refitted to all their support: three matches fix a pose to
        // about a cell, all of them to much less.
        best.iter()
            .map(|c| {
                let inliers = (0..m.len()).filter(|&k| {
                    c.pose.transform_point(from(k)).distance_squared(to(k))
                        <= INLIER_DISTANCE * INLIER_DISTANCE
                });
                let pose = rigid_fit(inliers.map(|k| (from(k), to(k)))).unwrap_or(c.pose);
                Candidate {
                    pose,
                    support: c.support,
                }
            })
            .collect()
    }
}

/// Map points per leaf of the [`FeatureTree`]: a leaf is searched by brute
/// force, which at this size costs less than splitting further.
const LEAF: usize = 16;

/// An exact k-d tree over the described map points' descriptors (those
/// with at least [`MIN_NEIGHBOURS`] neighbours): matching a frame's few
/// thousand points against all of the map's by brute force is most of a
/// relocalisation's time; descriptors cluster (planes, edges, corners), so
/// most of the tree is pruned even in 33 dimensions.
#[derive(Clone, Debug, Default)]
struct FeatureTree {
    /// Point indices, each leaf's contiguous.
    indices: Vec<u32>,
    nodes: Vec<Node>,
}

/// A node of a [`FeatureTree`].
#[derive(Clone, Copy, Debug)]
enum Node {
    /// Points `indices[start..end]`.
    Leaf { start: u32, end: u32 },
    /// Descriptors with `dim` below `value` go left (the next node), the
    /// others to node `right`.
    Split { dim: u8, value: f32, right: u32 },
}

impl FeatureTree {
    /// Rebuilds the tree over `cloud`'s usable descriptors.
    fn build(&mut self, cloud: &Cloud) {
        self.indices.clear();
        self.indices.extend(
            (0..cloud.points.len() as u32)
                .filter(|&j| cloud.neighbours[j as usize] >= MIN_NEIGHBOURS),
        );
        self.nodes.clear();
        let mut indices = std::mem::take(&mut self.indices);
        let n = indices.len();
        self.split(&cloud.features, &mut indices, 0, n);
        self.indices = indices;
    }

    /// Adds the subtree of `indices[start..end]`, splitting at the median
    /// of the dimension that spreads most.
    fn split(&mut self, features: &[Feature], indices: &mut [u32], start: usize, end: usize) {
        let here = &mut indices[start..end];
        if here.len() <= LEAF {
            self.nodes.push(Node::Leaf {
                start: start as u32,
                end: end as u32,
            });
            return;
        }
        let mut lo = [f32::INFINITY; FEATURE_LEN];
        let mut hi = [f32::NEG_INFINITY; FEATURE_LEN];
        for &j in here.iter() {
            for (d, &v) in features[j as usize].iter().enumerate() {
                lo[d] = lo[d].min(v);
                hi[d] = hi[d].max(v);
            }
        }
        let dim = (0..FEATURE_LEN)
            .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
            .unwrap_or(0);
        let mid = here.len() / 2;
        here.select_nth_unstable_by(mid, |&a, &b| {
            features[a as usize][dim].total_cmp(&features[b as usize][dim])
        });
        let value = features[here[mid] as usize][dim];
        let at = self.nodes.len();
        self.nodes.push(Node::Split {
            dim: dim as u8,
            value,
            right: 0,
        });
        self.split(features, indices, start, start + mid);
        let right = self.nodes.len() as u32;
        if let Node::Split { right: r, .. } = &mut self.nodes[at] {
            *r = right;
        }
        self.split(features, indices, start + mid, end);
    }

    /// The index of the descriptor in `features` nearest to `query`.
    fn nearest(&self, features: &[Feature], query: &Feature) -> Option<u32> {
        let mut best = (f32::INFINITY, None);
        if !self.nodes.is_empty() {
            self.search(0, features, query, &mut best);
        }
        best.1
    }

    fn search(
        &self,
        node: usize,
        features: &[Feature],
        query: &Feature,
        best: &mut (f32, Option<u32>),
    ) {
        match self.nodes[node] {
            Node::Leaf { start, end } => {
                for &j in &self.indices[start as usize..end as usize] {
                    let d = squared_distance(query, &features[j as usize], best.0);
                    if d < best.0 {
                        *best = (d, Some(j));
                    }
                }
            }
            Node::Split { dim, value, right } => {
                let diff = query[dim as usize] - value;
                let (near, far) = if diff < 0.0 {
                    (node + 1, right as usize)
                } else {
                    (right as usize, node + 1)
                };
                self.search(near, features, query, best);
                if diff * diff < best.0 {
                    self.search(far, features, query, best);
                }
            }
        }
    }
}

/// Squared distance between two descriptors, given up (returning at least
/// `limit`) once it exceeds `limit`.
fn squared_distance(a: &Feature, b: &Feature, limit: f32) -> f32 {
    let mut d = 0.0;
    for (ca, cb) in a.chunks_exact(BINS).zip(b.chunks_exact(BINS)) {
        d += ca
            .iter()
            .zip(cb)
            .map(|(x, y)| (x - y) * (x - y))
            .sum::<f32>();
        if d >= limit {
            return d;
        }
    }
    d
}

/// Inserts `c` into `best` (sorted, best first, at most `count`) unless a
/// better supported candidate within [`DISTINCT`] is there; a worse one
/// within it is replaced.
fn keep(best: &mut Vec<Candidate>, c: Candidate, count: usize) {
    let close = |o: &Candidate| {
        let d = o.pose.inverse().compose(&c.pose);
        d.translation.length() < DISTINCT && d.rotation_angle() < DISTINCT
    };
    if let Some(i) = best.iter().position(close) {
        if best[i].support >= c.support {
            return;
        }
        best.remove(i);
    }
    let at = best.partition_point(|o| o.support >= c.support);
    if at < count {
        best.insert(at, c);
        best.truncate(count);
    }
}
