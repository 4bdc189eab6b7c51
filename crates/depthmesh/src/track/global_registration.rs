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
//! bounded by [`MAX_MAP_CELLS`]. The map is described when the camera is
//! first lost and again at a loss after new keyframes were learnt.

use super::pyramid::{Level, Pyramid};
use crate::camera::{Intrinsics, Pose};
use crate::linalg::{horn, symmetric_eigen};
use crate::map::Mapper;
use glam::{DVec3, Vec3};
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

/// Normals are fitted to the points within this (metres): two cells,
/// Open3D's choice with FPFH, about a dozen points on a surface.
const NORMAL_RADIUS: f32 = 2.0 * VOXEL;

/// A normal is fitted only to this many points or more (the point itself
/// included); fewer keep the averaged measured normal.
const MIN_NORMAL_POINTS: f64 = 5.0;

/// Bins per angle of the histogram (Rusu et al.'s 11).
const BINS: usize = 11;

/// Length of a descriptor: three angles' histograms.
pub const FEATURE_LEN: usize = 3 * BINS;

/// One descriptor.
pub type Feature = [f32; FEATURE_LEN];

/// Points with fewer neighbours than this are not matched: their
/// histograms are mostly noise (a lone speck, a frame's corner).
const MIN_NEIGHBOURS: u32 = 8;

/// Points whose neighbourhood within [`FEATURE_RADIUS`] varies less from
/// a plane than this (surface variation, Pauly et al. 2002: the smallest
/// eigenvalue of the covariance over their sum) are not matched: a wall or
/// a floor looks the same everywhere, and matching it only adds wrong
/// matches. A plane with 1 cm of noise varies by about 0.003 (σ² over
/// R²/2); a point near an edge, with a tenth of its neighbours on the
/// other face, by about 0.02.
const MIN_VARIATION: f32 = 0.01;

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

/// Cells of the map kept at most: 250 m² of surface at 5 cm, a large flat
/// (the kitchen's first 150 frames give about 5 500 points). With its descriptor and
/// the buffers describing it, a cell takes about 400 bytes: 40 MB at
/// most. Once full, new views add nothing, as with the keyframes.
pub const MAX_MAP_CELLS: usize = 100_000;

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
    fitted: Vec<Vec3>,
    /// Surface variation within [`FEATURE_RADIUS`] of each point: the
    /// smallest eigenvalue of the neighbours' covariance over the sum.
    variation: Vec<f32>,
}

/// Sums for the covariance of points (relative to one of them).
#[derive(Clone, Copy, Debug, Default)]
struct Spread {
    sum: DVec3,
    products: [[f64; 3]; 3],
    count: f64,
}

impl Spread {
    fn add(&mut self, d: DVec3) {
        self.sum += d;
        for (a, row) in self.products.iter_mut().enumerate() {
            for (b, v) in row.iter_mut().enumerate() {
                *v += d[a] * d[b];
            }
        }
        self.count += 1.0;
    }

    /// Eigenvalues (ascending) and eigenvectors of the covariance.
    fn eigen(&self) -> Option<([f64; 3], [[f64; 3]; 3])> {
        if self.count < 3.0 {
            return None;
        }
        let mean = self.sum / self.count;
        let covariance: [[f64; 3]; 3] = std::array::from_fn(|a| {
            std::array::from_fn(|b| self.products[a][b] / self.count - mean[a] * mean[b])
        });
        Some(symmetric_eigen(&covariance))
    }
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
    /// Whether point `i` is matched: enough neighbours for a stable
    /// descriptor, and not inside a plane.
    fn distinctive(&self, i: usize) -> bool {
        self.neighbours[i] >= MIN_NEIGHBOURS && self.variation[i] >= MIN_VARIATION
    }

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
        // Normals from the spread of the points within NORMAL_RADIUS (the
        // least-spread direction), facing the way the measured ones do:
        // a normal from neighbouring pixels of a noisy low-resolution depth
        // image is off by 10–20°, more than a histogram bin, and a plane
        // would then look like anything.
        let measured = &self.normals;
        self.fitted.resize(n, Vec3::ZERO);
        self.variation.resize(n, 0.0);
        self.fitted
            .par_iter_mut()
            .zip(self.variation.par_iter_mut())
            .enumerate()
            .for_each(|(i, (out, variation))| {
                let p = search.points[i];
                let mut near = Spread::default();
                let mut wide = Spread::default();
                near.add(DVec3::ZERO);
                wide.add(DVec3::ZERO);
                search.each(i, |j, d2| {
                    let d = (search.points[j] - p).as_dvec3();
                    wide.add(d);
                    if d2 <= NORMAL_RADIUS * NORMAL_RADIUS {
                        near.add(d);
                    }
                });
                *variation = wide.eigen().map_or(0.0, |(values, _)| {
                    (values[0] / values.iter().sum::<f64>().max(f64::MIN_POSITIVE)) as f32
                });
                *out = measured[i];
                if near.count < MIN_NORMAL_POINTS {
                    return;
                }
                let Some((_, vectors)) = near.eigen() else {
                    return;
                };
                let fitted = DVec3::from_array(vectors[0]).as_vec3().normalize_or_zero();
                if fitted != Vec3::ZERO {
                    *out = if fitted.dot(measured[i]) < 0.0 {
                        -fitted
                    } else {
                        fitted
                    };
                }
            });
        std::mem::swap(&mut self.normals, &mut self.fitted);
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

/// The map's surface seen from the keyframes, as described points.
#[derive(Clone, Debug, Default)]
pub struct MapFeatures {
    cells: HashMap<u64, Cell>,
    /// The poses whose views were described.
    described: Vec<Pose>,
    cloud: Cloud,
    /// The described points' descriptors, for nearest-neighbour search.
    tree: FeatureTree,
    view: Pyramid,
}

impl MapFeatures {
    /// Describes the map's surface seen from `poses` (the keyframes'),
    /// rendered with `k`, unless it was last described from the same
    /// poses. Every view is rendered again, from the map as it is now, so
    /// the description depends on the map and the poses alone, not on when
    /// the camera was lost before: a run resumed from a checkpoint finds
    /// what an uninterrupted one finds.
    pub fn update(&mut self, map: &dyn Mapper, poses: &[Pose], k: &Intrinsics) {
        if poses == self.described.as_slice() {
            return;
        }
        self.cells.clear();
        for pose in poses {
            let depth = map.render_depth(k, pose);
            self.view.build(&depth, k, 1);
            accumulate(&self.view.levels[0], pose, &mut self.cells, MAX_MAP_CELLS);
        }
        self.described.clear();
        self.described.extend_from_slice(poses);
        self.cloud.build(&self.cells);
        self.tree.build(&self.cloud);
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
    /// Matches within 1.5 [`VOXEL`] at that pose.
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
                .filter(|&i| frame.distinctive(i))
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
        self.indices
            .extend((0..cloud.points.len() as u32).filter(|&j| cloud.distinctive(j as usize)));
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

#[cfg(test)]
mod tests {
    use super::super::filter::{Bilateral, BilateralParams};
    use super::super::tracker::tests::{scene, SceneMap, ROOM};
    use super::*;
    use crate::sim::{NoiseModel, SimulatedSensor};

    /// The room with clutter of different shapes and orientations, as a
    /// kitchen has: the bare room is boxes, whose edges and corners all
    /// look alike.
    const CLUTTER: &str = r#"
[[object]]
shape = "sphere"
radius = 0.25
translation = [0.8, 0.25, -0.4]
[[object]]
shape = "cylinder"
radius = 0.12
height = 0.6
translation = [-0.8, 0.3, 0.7]
[[object]]
shape = "box"
size = [0.4, 0.35, 0.3]
translation = [0.6, 0.175, 0.9]
rotation = [0.0, 30.0, 0.0]
[[object]]
shape = "box"
size = [0.3, 0.3, 0.5]
translation = [-1.0, 0.35, -0.8]
rotation = [20.0, 45.0, 0.0]
[[object]]
shape = "sphere"
radius = 0.12
translation = [0.2, 0.87, 0.1]
[[object]]
shape = "cylinder"
radius = 0.05
height = 0.3
translation = [-0.3, 0.9, -0.2]
"#;

    /// Points on the faces of two boxes, with outward normals, about a
    /// cell apart, each moved at random within its face: on a regular grid
    /// many pairs are exactly symmetric about an edge, where which point's
    /// frame the pair angles are taken in is decided by rounding (and the
    /// angle flips sign). No two faces facing each other are within the
    /// feature radius: the angle between opposite normals is ±180°, at the
    /// histogram's border, and rounding picks either end.
    fn two_boxes() -> (Vec<Vec3>, Vec<Vec3>) {
        let (mut points, mut normals) = (Vec::new(), Vec::new());
        let mut rng = SmallRng::seed_from_u64(3);
        for (centre, half) in [
            (Vec3::ZERO, Vec3::new(0.6, 0.3, 0.4)),
            (Vec3::new(1.2, -0.1, 0.2), Vec3::new(0.2, 0.2, 0.3)),
        ] {
            for axis in 0..3 {
                for sign in [-1.0f32, 1.0] {
                    let mut n = Vec3::ZERO;
                    n[axis] = sign;
                    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                    let step = 0.047;
                    let steps = |a: usize| (half[a] * 2.0 / step) as i32;
                    for i in 0..=steps(u) {
                        for j in 0..=steps(v) {
                            let mut p = centre + n * half[axis];
                            p[u] += -half[u] + (i as f32 + rng.gen_range(0.0..0.5)) * step;
                            p[v] += -half[v] + (j as f32 + rng.gen_range(0.0..0.5)) * step;
                            points.push(p);
                            normals.push(n);
                        }
                    }
                }
            }
        }
        (points, normals)
    }

    fn described(points: Vec<Vec3>, normals: Vec<Vec3>) -> Cloud {
        let mut cloud = Cloud {
            points,
            normals,
            ..Cloud::default()
        };
        cloud.describe();
        cloud
    }

    #[test]
    fn descriptors_do_not_change_with_where_the_surface_is() {
        let (points, normals) = two_boxes();
        let motion = Pose::look_at(Vec3::new(1.0, 2.0, -3.0), Vec3::new(0.3, 0.1, 0.5), Vec3::Y);
        let moved = described(
            points.iter().map(|p| motion.transform_point(*p)).collect(),
            normals
                .iter()
                .map(|n| motion.transform_vector(*n))
                .collect(),
        );
        let still = described(points, normals);
        assert!(still.neighbours.iter().all(|&k| k >= MIN_NEIGHBOURS));
        let mut worst = 0.0f32;
        for (a, b) in still.features.iter().zip(&moved.features) {
            // Each angle's histogram sums to 200 (the point's own 100 and
            // its neighbours' weighted 100).
            assert!((a.iter().sum::<f32>() - 600.0).abs() < 0.1, "{a:?}");
            let dd = squared_distance(a, b, f32::INFINITY).sqrt();
            worst = worst.max(dd);
        }
        // Angles at bin borders may fall either side after rounding: a
        // few per mille of the histograms' mass.
        assert!(worst < 5.0, "descriptors differ by {worst}");
        // Yet they tell points apart (on a face, near an edge, near a
        // corner): the median distance between different points' descriptors
        // is many times that.
        let n = still.features.len();
        let mut apart: Vec<f32> = (0..n)
            .map(|i| {
                squared_distance(
                    &still.features[i],
                    &still.features[(i + n / 3) % n],
                    f32::INFINITY,
                )
                .sqrt()
            })
            .collect();
        apart.sort_by(f32::total_cmp);
        assert!(apart[n / 2] > 20.0, "median {}", apart[n / 2]);
    }

    #[test]
    fn the_tree_finds_the_nearest_descriptor() {
        let (points, normals) = two_boxes();
        let cloud = described(points, normals);
        let mut tree = FeatureTree::default();
        tree.build(&cloud);
        let mut rng = SmallRng::seed_from_u64(1);
        for _ in 0..200 {
            let mut query = cloud.features[rng.gen_range(0..cloud.features.len())];
            query
                .iter_mut()
                .for_each(|v| *v += rng.gen_range(-5.0..5.0));
            // Only distinctive points are in the tree.
            let brute = (0..cloud.features.len())
                .filter(|&j| cloud.distinctive(j))
                .map(|j| squared_distance(&query, &cloud.features[j], f32::INFINITY))
                .fold(f32::INFINITY, f32::min);
            let j = tree.nearest(&cloud.features, &query).unwrap() as usize;
            assert_eq!(
                squared_distance(&query, &cloud.features[j], f32::INFINITY),
                brute
            );
        }
    }

    #[test]
    fn a_frame_is_registered_to_a_map_seen_only_from_elsewhere() {
        let text = format!("{ROOM}\n{CLUTTER}");
        let room = scene(&text);
        let map = SceneMap::new(&room, 0);
        let k = Intrinsics::from_vertical_fov(160, 120, 60.0);
        let centre = Vec3::new(0.0, 0.4, 0.0);
        // The map seen from poses a quarter of the way around the room,
        // 2 m out at 1.3 m, as a camera that passed there saw it.
        let views: Vec<Pose> = (0..=8)
            .map(|i| {
                let a = (10.0 * i as f32).to_radians();
                Pose::look_at(
                    Vec3::new(2.0 * a.cos(), 1.3, 2.0 * a.sin()),
                    centre,
                    Vec3::Y,
                )
            })
            .collect();
        let mut features = MapFeatures::default();
        features.update(&map, &views, &k);
        assert!(features.cloud().points.len() > 500);
        // The frame: nearer the middle and higher than every view, more
        // than half a metre from each, looking down past the table.
        let truth = Pose::look_at(
            Vec3::new(1.0, 1.7, 1.0),
            Vec3::new(-0.5, 0.2, -0.9),
            Vec3::Y,
        );
        assert!(views
            .iter()
            .all(|v| v.translation.distance(truth.translation) > 0.5));
        let mut sensor = SimulatedSensor::new(k, 0.4, 6.0, NoiseModel::Kinect, 2).unwrap();
        // Smoothed as the tracker smooths every frame.
        let mut smoothed = crate::image::DepthImage::default();
        Bilateral::new(BilateralParams::default())
            .unwrap()
            .apply(&sensor.capture(&room, 1, &truth).depth, &mut smoothed);
        let mut frame = Pyramid::default();
        frame.build(&smoothed, &k, 1);
        let mut registration = GlobalRegistration::default();
        let found = registration.candidates(&frame.levels[0], &features, 3);
        // Within ICP's reach: a few centimetres and degrees.
        let best = found.first().expect("no candidate");
        let d = best.pose.inverse().compose(&truth);
        assert!(
            d.translation.length() < 0.05 && d.rotation_angle().to_degrees() < 3.0,
            "{:.3} m, {:.2}° (support {})",
            d.translation.length(),
            d.rotation_angle().to_degrees(),
            best.support
        );
    }
}
