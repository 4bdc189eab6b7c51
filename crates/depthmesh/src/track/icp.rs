//! One step of projective point-to-plane ICP (KinectFusion): associate each
//! frame point with the model point seen through the same pixel, build the
//! 6×6 normal equations of the linearised point-to-plane error, solve.

use super::pyramid::Level;
use crate::camera::{Intrinsics, Pose};
use crate::linalg::symmetric_eigen;
use glam::{Quat, Vec3};
use rayon::prelude::*;

/// Which associations count as the same surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Association {
    /// Largest distance between a frame point and its model point (metres).
    pub max_distance: f32,
    /// Smallest cosine of the angle between their normals.
    pub min_normal_cos: f32,
    /// Give every normal orientation present the same total say
    /// (normal-space weighting, at most 4× a point).
    pub balance: bool,
    /// Half-width, in model-view pixels, of the window searched for the
    /// nearest model point when the pixel a frame point projects to holds
    /// none within the distance and angle (0: that pixel alone). From a
    /// start centimetres off, a structure narrower than the offset (a
    /// lamp's pole) projects onto what lies behind it, and projective
    /// association alone drops the one surface that pins the motion.
    pub window: usize,
}

/// The normal equations `A·x = -b` of one ICP iteration, summed over the
/// inlier associations (upper triangle of `A` packed row by row).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Equations {
    ata: [f64; 21],
    atb: [f64; 6],
    /// Sum of squared point-to-plane errors of the inliers.
    pub squared_error: f64,
    /// Sum of squared distances of the inliers from the model camera, for
    /// putting rotations and translations on one scale.
    pub squared_range: f64,
    /// Associations accepted.
    pub inliers: usize,
    /// Frame points that had a normal (the candidates).
    pub candidates: usize,
}

impl Equations {
    /// Adds the sums of one row of pixels.
    fn add_row(&mut self, row: &RowSums) {
        for (a, &b) in self.ata.iter_mut().zip(&row.ata) {
            *a += f64::from(b);
        }
        for (a, &b) in self.atb.iter_mut().zip(&row.atb) {
            *a += f64::from(b);
        }
        self.squared_error += f64::from(row.squared_error);
        self.squared_range += f64::from(row.squared_range);
        self.inliers += row.inliers;
        self.candidates += row.candidates;
    }

    fn merge(mut self, other: Equations) -> Equations {
        for (a, b) in self.ata.iter_mut().zip(other.ata) {
            *a += b;
        }
        for (a, b) in self.atb.iter_mut().zip(other.atb) {
            *a += b;
        }
        self.squared_error += other.squared_error;
        self.squared_range += other.squared_range;
        self.inliers += other.inliers;
        self.candidates += other.candidates;
        self
    }

    /// The full symmetric matrix `A`.
    #[allow(clippy::needless_range_loop)] // Row and column indices of a packed triangle.
    pub fn matrix(&self) -> [[f64; 6]; 6] {
        let mut a = [[0.0; 6]; 6];
        let mut k = 0;
        for r in 0..6 {
            for c in r..6 {
                a[r][c] = self.ata[k];
                a[c][r] = self.ata[k];
                k += 1;
            }
        }
        a
    }

    /// Root mean square point-to-plane error of the inliers (metres).
    pub fn rms(&self) -> f64 {
        (self.squared_error / self.inliers.max(1) as f64).sqrt()
    }

    /// How well the inliers pin down all six degrees of freedom: the
    /// smallest eigenvalue of the per-inlier mean of `A`, with rotations
    /// scaled by the points' RMS range so that both halves are in metres.
    /// 1/3 for three orthogonal planes filling the view, near 0 for a
    /// single plane (which leaves two translations and a rotation free).
    pub fn conditioning(&self) -> f64 {
        match self.scaled() {
            Some((a, _, _)) => symmetric_eigen(&a).0[0],
            None => 0.0,
        }
    }

    /// RMS distance of the inliers from the model camera (metres): a
    /// rotation by an angle moves them about this far per radian.
    pub fn rms_range(&self) -> f64 {
        (self.squared_range / self.inliers.max(1) as f64).sqrt()
    }

    /// The system of [`Equations::conditioning`]: `S·A·S/n` and `S·b/n`,
    /// and the scale `S` (1/range for the rotations, 1 for the
    /// translations), so that `x = S·y` solves `A·x = -b` when `y` solves
    /// the scaled one; `None` without inliers.
    pub fn scaled(&self) -> Option<Scaled> {
        if self.inliers == 0 {
            return None;
        }
        let n = self.inliers as f64;
        let range = self.rms_range().max(1e-6);
        let scale = [1.0 / range, 1.0 / range, 1.0 / range, 1.0, 1.0, 1.0];
        let mut a = self.matrix();
        for (r, row) in a.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v *= scale[r] * scale[c] / n;
            }
        }
        let b = std::array::from_fn(|i| self.atb[i] * scale[i] / n);
        Some((a, b, scale))
    }
}

/// A range-scaled system: `S·A·S/n`, `S·b/n` and the diagonal of `S`.
pub type Scaled = ([[f64; 6]; 6], [f64; 6], [f64; 6]);

/// The sums of one row of pixels, in `f32` (the vector unit does twice as
/// many as in `f64`): a row is a few hundred terms, whose `f32` sum is exact
/// to about 1e-5 — far below the noise — before it joins the `f64` total.
#[derive(Default)]
struct RowSums {
    ata: [f32; 21],
    atb: [f32; 6],
    squared_error: f32,
    squared_range: f32,
    inliers: usize,
    candidates: usize,
}

impl RowSums {
    #[inline(always)]
    fn add(&mut self, j: [f32; 6], e: f32, range2: f32) {
        let mut k = 0;
        for r in 0..6 {
            for c in r..6 {
                self.ata[k] += j[r] * j[c];
                k += 1;
            }
            self.atb[r] += j[r] * e;
        }
        self.squared_error += e * e;
        self.squared_range += range2;
        self.inliers += 1;
    }
}

/// Builds the normal equations for moving `frame` (its camera-space points)
/// onto `model` (camera-space points of the model camera), where
/// `frame_to_model` is the current estimate of the frame camera in the
/// model camera's axes.
pub fn equations(
    frame: &Level,
    model: &Level,
    frame_to_model: &Pose,
    assoc: &Association,
) -> Equations {
    let weights = if assoc.balance {
        bin_weights(&frame.normals)
    } else {
        [1.0; 6]
    };
    fold_matches(
        frame,
        model,
        frame_to_model,
        assoc,
        1,
        |row: &mut RowSums, m| {
            let s = weights[normal_bin(m.frame_normal)];
            row.add(
                jacobian_row(m.point, m.model_normal).map(|j| j * s),
                m.offset.dot(m.model_normal) * s,
                m.point.length_squared(),
            );
        },
    )
}

/// The normal equations of [`equations`] at `frame_to_model`, for weighing
/// what the data say against a prediction: one frame pixel per `block` ×
/// `block` block counts (the first), and each model normal is replaced by
/// the mean of those within `radius` model pixels that lie on its surface
/// (depth within 2 %, normals within 37°).
///
/// A fused map's errors are its voxels', a few pixels across, not each
/// pixel's: counted pixel by pixel, one voxel's error counts as many
/// independent observations. And its normals lean a few degrees every
/// which way, which reads as information along a plane: a floor with one
/// small box, orbited, showed a median of 1.2e-4 per inlier along the
/// orbit against the map, 1.4e-5 against the scene's exact normals, and
/// 1.6e-5 against the map's normals averaged over 9 × 9 pixels (the exact
/// normals' figure does not move when they are averaged).
pub fn block_equations(
    frame: &Level,
    model: &Level,
    frame_to_model: &Pose,
    assoc: &Association,
    block: usize,
    radius: usize,
) -> Equations {
    fold_matches(
        frame,
        model,
        frame_to_model,
        assoc,
        block,
        |row: &mut RowSums, m| {
            // Around the point's own pixel: with a window the match may be a
            // neighbour's, but weighing is asked for only while the camera is
            // followed, where the window is 0.
            let mn = surface_normal(model, m.pixel, radius);
            if mn != Vec3::ZERO {
                row.add(
                    jacobian_row(m.point, mn),
                    m.offset.dot(mn),
                    m.point.length_squared(),
                );
            }
        },
    )
}

/// The mean of the normals within `radius` pixels of model pixel `(u, v)`
/// that lie on its surface: depth within 2 % of its own, normal within 37°.
fn surface_normal(model: &Level, (u, v): (usize, usize), radius: usize) -> Vec3 {
    let (mw, mh) = model.size();
    let i = v * mw + u;
    let (n0, z0) = (model.normals[i], model.points[i].z);
    let mut sum = Vec3::ZERO;
    for y in v.saturating_sub(radius)..(v + radius + 1).min(mh) {
        for x in u.saturating_sub(radius)..(u + radius + 1).min(mw) {
            let j = y * mw + x;
            let n = model.normals[j];
            if n.dot(n0) > 0.8 && (model.points[j].z - z0).abs() < 0.02 * z0 {
                sum += n;
            }
        }
    }
    sum.normalize_or_zero()
}

/// How firmly the map's view pins `frame` along one `direction` of motion
/// (a unit vector of the range-scaled system of [`Equations::scaled`]:
/// rotation × `range`, then translation): the mean over all inliers of
/// `(J·v)²`, counting only rows whose normal faces the way the motion moves
/// their point, by at least `facing` (the cosine between them). An
/// eigenvalue counts every row, also those that lean towards the direction
/// only by the noise of their normals; looking along a corridor whose walls
/// and floor fill the view, that noise made up all but a thousandth of it
/// along the corridor.
///
/// The cosine, not `|J·v|` itself: along a turn about a point ahead (a
/// camera carried round a table it looks at) the points near that point
/// hardly move, and no row reached a bar set for `|J·v|`, also where the
/// table's sides face the motion squarely.
pub fn facing_information(
    frame: &Level,
    model: &Level,
    frame_to_model: &Pose,
    assoc: &Association,
    (direction, range): ([f64; 6], f64),
    facing: f64,
) -> f64 {
    let [rx, ry, rz, tx, ty, tz] = direction;
    let (turn, shift) = (glam::DVec3::new(rx, ry, rz), glam::DVec3::new(tx, ty, tz));
    let (sum, inliers) = fold_matches(
        frame,
        model,
        frame_to_model,
        assoc,
        1,
        |(sum, inliers): &mut (f64, usize), m| {
            // How the motion moves the point: J·v is its component along
            // the normal.
            let p = m.point.as_dvec3();
            let moved = (turn / range).cross(p) + shift;
            let along = m.model_normal.as_dvec3().dot(moved);
            *inliers += 1;
            if along.abs() >= facing * moved.length() {
                *sum += along * along;
            }
        },
    );
    sum / inliers.max(1) as f64
}

/// A frame point associated with the model (see [`matched`]).
struct Match {
    /// The frame point's normal, in the frame camera.
    frame_normal: Vec3,
    /// The frame point moved into the model camera.
    point: Vec3,
    /// `point` less the model point it is associated with.
    offset: Vec3,
    /// The model point's normal.
    model_normal: Vec3,
    /// The model pixel `point` projects to.
    pixel: (usize, usize),
}

/// Sums over the frame points with a normal, every `step`-th point of every
/// `step`-th row: each counts as a candidate ([`Accumulate::candidate`]),
/// and `add` puts the term of one matched in the model into its row's
/// sums; the rows are totalled with [`Accumulate::add_row`] (for the
/// normal equations, each row's `f32` sums join an `f64` total, as
/// [`RowSums`] says).
fn fold_matches<R: Accumulate>(
    frame: &Level,
    model: &Level,
    frame_to_model: &Pose,
    assoc: &Association,
    step: usize,
    add: impl Fn(&mut R, Match) + Sync,
) -> R::Total {
    let (w, _) = frame.size();
    let Some(mk) = model.intrinsics else {
        return R::Total::default();
    };
    let max_d2 = assoc.max_distance * assoc.max_distance;
    let step = step.max(1);
    frame
        .points
        .par_chunks(w * step)
        .zip(frame.normals.par_chunks(w * step))
        .fold(R::Total::default, |mut total, (rows, normals)| {
            let mut row = R::default();
            // The first row of each `step` rows (chunks, not a stepped
            // iterator over rows), and an index stepped by hand: `step_by`
            // over the pixels made the kitchen's tracking 10 % slower, and
            // a closure per pixel was not inlined.
            let (points, normals) = (&rows[..w], &normals[..w]);
            let mut x = 0;
            while x < w {
                let (p, n) = (points[x], normals[x]);
                if n != Vec3::ZERO {
                    row.candidate();
                    if let Some(m) = matched(model, &mk, frame_to_model, assoc, max_d2, p, n) {
                        add(&mut row, m);
                    }
                }
                x += step;
            }
            R::add_row(&mut total, row);
            total
        })
        .reduce(R::Total::default, R::merge)
}

/// Per-row sums of [`fold_matches`] and how they are totalled.
trait Accumulate: Default {
    /// The sum over all rows.
    type Total: Default + Send;
    /// Counts a frame point tried for a match, matched or not (nothing, if
    /// the sums do not count them).
    fn candidate(&mut self) {}
    /// Adds one row's sums to `total`.
    fn add_row(total: &mut Self::Total, row: Self);
    /// Two totals' sum.
    fn merge(a: Self::Total, b: Self::Total) -> Self::Total;
}

impl Accumulate for RowSums {
    type Total = Equations;
    fn candidate(&mut self) {
        self.candidates += 1;
    }
    fn add_row(total: &mut Equations, row: RowSums) {
        total.add_row(&row);
    }
    fn merge(a: Equations, b: Equations) -> Equations {
        a.merge(b)
    }
}

/// A sum of squares and its count.
impl Accumulate for (f64, usize) {
    type Total = (f64, usize);
    fn add_row(total: &mut (f64, usize), row: (f64, usize)) {
        total.0 += row.0;
        total.1 += row.1;
    }
    fn merge(a: (f64, usize), b: (f64, usize)) -> (f64, usize) {
        (a.0 + b.0, a.1 + b.1)
    }
}

/// The row of the point-to-plane Jacobian for a frame point at `p` (in the
/// model camera) matched with a model normal `mn`: how a motion (rotation
/// as a scaled axis, then translation) moves the point along the normal.
#[inline(always)]
fn jacobian_row(p: Vec3, mn: Vec3) -> [f32; 6] {
    let r = p.cross(mn);
    [r.x, r.y, r.z, mn.x, mn.y, mn.z]
}

/// Frame point `p` with normal `n`, moved into the model camera by
/// `frame_to_model`, and what it is associated with there (see
/// [`associate`]), if anything.
#[inline(always)]
fn matched(
    model: &Level,
    mk: &Intrinsics,
    frame_to_model: &Pose,
    assoc: &Association,
    max_d2: f32,
    p: Vec3,
    n: Vec3,
) -> Option<Match> {
    let point = frame_to_model.transform_point(p);
    let pixel = project(mk, model.size(), point)?;
    let normal = frame_to_model.transform_vector(n);
    let (offset, model_normal) = associate(model, pixel, point, normal, assoc, max_d2)?;
    Some(Match {
        frame_normal: n,
        point,
        offset,
        model_normal,
        pixel,
    })
}

/// The model pixel camera-space point `p` projects to, if it lies in
/// front of the camera and inside the `(width, height)` view.
#[inline(always)]
fn project(mk: &Intrinsics, (mw, mh): (usize, usize), p: Vec3) -> Option<(usize, usize)> {
    if p.z <= 0.0 {
        return None;
    }
    // Nearest pixel, rounding by truncation of the shifted coordinate
    // (`round` is a library call on baseline x86-64; so is a conversion
    // to an unsigned integer).
    let inv_z = 1.0 / p.z;
    let u = mk.fx * p.x * inv_z + mk.cx + 0.5;
    let v = mk.fy * p.y * inv_z + mk.cy + 0.5;
    if !(u >= 0.0 && v >= 0.0 && u < mw as f32 && v < mh as f32) {
        return None;
    }
    Some((u as i32 as usize, v as i32 as usize))
}

/// The model point that frame point `p` with normal `n` (both in the model
/// camera's frame), projecting to `pixel` of the model view, is associated
/// with: the difference `p − m` and the model normal. The point seen
/// through that pixel if it lies within the distance and angle, else the
/// nearest that does within [`Association::window`] pixels.
#[inline(always)]
fn associate(
    model: &Level,
    (u, v): (usize, usize),
    p: Vec3,
    n: Vec3,
    assoc: &Association,
    max_d2: f32,
) -> Option<(Vec3, Vec3)> {
    let (mw, mh) = model.size();
    let candidate = |i: usize| {
        let mn = model.normals[i];
        if mn == Vec3::ZERO {
            return None;
        }
        let d = p - model.points[i];
        let d2 = d.length_squared();
        (d2 <= max_d2 && n.dot(mn) >= assoc.min_normal_cos).then_some((d2, d, mn))
    };
    if let Some((_, d, mn)) = candidate(v * mw + u) {
        return Some((d, mn));
    }
    let r = assoc.window;
    if r == 0 {
        return None;
    }
    let mut nearest: Option<(f32, Vec3, Vec3)> = None;
    for y in v.saturating_sub(r)..(v + r + 1).min(mh) {
        for x in u.saturating_sub(r)..(u + r + 1).min(mw) {
            if let Some(c) = candidate(y * mw + x) {
                if nearest.is_none_or(|b| c.0 < b.0) {
                    nearest = Some(c);
                }
            }
        }
    }
    nearest.map(|(_, d, mn)| (d, mn))
}

/// The bin of a normal by its dominant axis and sign (six bins).
#[inline(always)]
fn normal_bin(n: Vec3) -> usize {
    let a = n.abs();
    let axis = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    2 * axis + usize::from(n[axis] < 0.0)
}

/// Per normal bin, the square root of the weight that gives every
/// orientation present the same total say (normal-space weighting,
/// Rusinkiewicz and Levoy 2001): a floor filling most of the view no longer
/// drowns the few points that pin the motion along it. At most 4× a point.
fn bin_weights(normals: &[Vec3]) -> [f32; 6] {
    let mut counts = [0usize; 6];
    for &n in normals {
        if n != Vec3::ZERO {
            counts[normal_bin(n)] += 1;
        }
    }
    let total: usize = counts.iter().sum();
    let used = counts.iter().filter(|&&c| c > 0).count().max(1);
    counts.map(|c| {
        if c == 0 {
            0.0
        } else {
            (total as f32 / (used * c) as f32).min(4.0).sqrt()
        }
    })
}

/// Applies a small motion (rotation ω as a scaled axis, translation t) on
/// the left of `pose`: `x ↦ R(ω)·pose(x) + t`.
pub fn apply_motion(pose: &Pose, omega: [f64; 3], t: [f64; 3]) -> Pose {
    let w = Vec3::new(omega[0] as f32, omega[1] as f32, omega[2] as f32);
    let rotation = glam::Mat3::from_quat(Quat::from_scaled_axis(w));
    let motion = Pose::new(rotation, Vec3::new(t[0] as f32, t[1] as f32, t[2] as f32));
    let moved = motion.compose(pose);
    // Keep the rotation orthonormal as updates accumulate in f32.
    Pose::from_quat(moved.quat(), moved.translation)
}

/// How far a frame agrees with a model view (see [`agreement`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Agreement {
    /// Of the frame's measured points, the fraction within the distance
    /// of the model's surface.
    pub overlap: f64,
    /// Of the frame's points that fall on the model's surface (a model
    /// pixel with a point), the fraction within the distance of it: where
    /// the map has seen surface, whether the frame sees the same.
    pub on_surface: f64,
    /// Of the frame's measured points, the fraction that fall on the
    /// model's surface but farther than the distance from it: seen in
    /// front of it or through it.
    pub contradicted: f64,
    /// RMS distance of the points within the distance (metres).
    pub rms: f64,
}

/// How far a frame agrees with a model view, for verifying a pose found
/// without a prediction: which of the frame's measured points (normals or
/// not) land within `distance` of the model's surface, among all of them
/// and among those that fall where the model has surface. The surface at a
/// model pixel is the plane through its point (the point alone where it
/// has no normal): the view is coarser than the frame, and on a slanted or
/// distant surface a point on it can lie centimetres from the pixel's
/// centre (a correct pose on 7-Scenes matched 48 % of the frame point to
/// point, 50 % being the bar then).
pub fn agreement(frame: &Level, model: &Level, frame_to_model: &Pose, distance: f32) -> Agreement {
    agreement_beside(frame, model, frame_to_model, distance, |_| false)
}

/// [`agreement`] without the points in front of the model's surface, beyond
/// the distance, for which `moved_in` holds (given in the model's camera
/// coordinates): something nearer than the surface that moved into view
/// and hides it ([`crate::track::moved_in`]). Such a point is not counted at
/// all, as if the frame had not measured it.
pub fn agreement_beside(
    frame: &Level,
    model: &Level,
    frame_to_model: &Pose,
    distance: f32,
    moved_in: impl Fn(Vec3) -> bool + Sync,
) -> Agreement {
    let size = model.size();
    let Some(mk) = model.intrinsics else {
        return Agreement::default();
    };
    let max_d2 = distance * distance;
    let (measured, on_surface, near, squared) = frame
        .points
        .par_iter()
        .fold(
            || (0usize, 0usize, 0usize, 0.0f64),
            |(measured, on_surface, near, squared), &p| {
                if p.z <= 0.0 {
                    return (measured, on_surface, near, squared);
                }
                let q = frame_to_model.transform_point(p);
                let off = project(&mk, size, q).and_then(|(u, v)| {
                    let i = v * size.0 + u;
                    (model.points[i].z > 0.0).then(|| {
                        let (m, n) = (model.points[i], model.normals[i]);
                        let d2 = if n == Vec3::ZERO {
                            (q - m).length_squared()
                        } else {
                            n.dot(q - m).powi(2)
                        };
                        (d2, q.z < m.z)
                    })
                });
                match off {
                    Some((d2, true)) if d2 > max_d2 && moved_in(q) => {
                        (measured, on_surface, near, squared)
                    }
                    Some((d2, _)) if d2 <= max_d2 => (
                        measured + 1,
                        on_surface + 1,
                        near + 1,
                        squared + f64::from(d2),
                    ),
                    Some(_) => (measured + 1, on_surface + 1, near, squared),
                    None => (measured + 1, on_surface, near, squared),
                }
            },
        )
        .reduce(
            || (0, 0, 0, 0.0),
            |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2, a.3 + b.3),
        );
    Agreement {
        overlap: near as f64 / measured.max(1) as f64,
        on_surface: near as f64 / on_surface.max(1) as f64,
        contradicted: (on_surface - near) as f64 / measured.max(1) as f64,
        rms: (squared / near.max(1) as f64).sqrt(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;
    use crate::image::DepthImage;
    use crate::track::pyramid::Pyramid;

    /// One level of a 64×48 view whose pixel `(u, v)` sees depth `f(u, v)`.
    fn level(f: impl Fn(u32, u32) -> f32) -> Level {
        let k = Intrinsics::from_vertical_fov(64, 48, 60.0);
        let mut depth = DepthImage::new(64, 48);
        for v in 0..48 {
            for u in 0..64 {
                depth.data[(v * 64 + u) as usize] = f(u, v);
            }
        }
        let mut pyramid = Pyramid::default();
        pyramid.build(&depth, &k, 1);
        pyramid.levels.swap_remove(0)
    }

    #[test]
    fn the_window_finds_a_thin_surface_its_own_pixel_misses() {
        // A strip at 1 m, pixels 20–25 wide (normals on 21–24), before a
        // wall at 3 m; a frame point on the strip's middle seen 8 pixels
        // to the right, where the model view has the wall.
        let model = level(|u, _| if (20..26).contains(&u) { 1.0 } else { 3.0 });
        let k = model.intrinsics.unwrap();
        let p = model.points[24 * 64 + 23] + Vec3::X * (8.0 / k.fx);
        let n = Vec3::NEG_Z;
        let find = |pixel, point, window| {
            let assoc = Association {
                max_distance: 0.3,
                min_normal_cos: 0.9,
                balance: false,
                window,
            };
            associate(&model, pixel, point, n, &assoc, 0.09)
        };
        assert_eq!(find((31, 24), p, 0), None);
        // Its nearest strip point with a normal is 7 pixels away.
        assert_eq!(find((31, 24), p, 6), None);
        let (d, normal) = find((31, 24), p, 8).expect("the strip within 8 pixels");
        let nearest = p - model.points[24 * 64 + 24];
        assert!((d - nearest).length() < 1e-6, "{d} against {nearest}");
        assert!(normal.dot(n) > 0.99, "{normal}");
        // Where its own pixel holds a point within reach, that one is
        // kept, however near another lies in the window.
        let on_wall = model.points[24 * 64 + 40] + Vec3::Z * 0.05;
        let (d, _) = find((40, 24), on_wall, 8).unwrap();
        assert!((d - Vec3::Z * 0.05).length() < 1e-6, "{d}");
    }

    #[test]
    fn facing_information_counts_only_the_points_that_face_a_direction() {
        // A wall through (0, 0, 2 m) turned `degrees` about the vertical,
        // seen by a frame that matches it where it is.
        let facing = |degrees: f32, direction: [f64; 6]| {
            let k = Intrinsics::from_vertical_fov(64, 48, 60.0);
            let tan = degrees.to_radians().tan();
            let wall = level(|u, _| 2.0 / (1.0 + tan * (u as f32 - k.cx) / k.fx));
            let assoc = Association {
                max_distance: 0.1,
                min_normal_cos: 0.9,
                balance: false,
                window: 0,
            };
            facing_information(
                &wall,
                &wall,
                &Pose::IDENTITY,
                &assoc,
                (direction, 2.0),
                0.34,
            )
        };
        let (along, across) = (
            [0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        );
        // Facing the camera, the wall pins the motion towards it fully
        // and the motion along it not at all.
        assert!((facing(0.0, across) - 1.0).abs() < 0.01);
        assert_eq!(facing(0.0, along), 0.0);
        // Turned 10°, every normal leans along the wall by sin 10°: an
        // eigenvalue counts that (0.03), a facing row does not.
        assert_eq!(facing(10.0, along), 0.0);
        // Turned 30°, every row faces it by sin 30°.
        let turned = facing(30.0, along);
        assert!((turned - 0.25).abs() < 0.01, "{turned}");
    }

    #[test]
    fn a_turn_about_a_point_ahead_is_pinned_by_a_surface_there_facing_it() {
        // A board 1 m wide facing the camera 2 m ahead (a table's side),
        // and the camera carried round the vertical through its middle:
        // the board's points move along its normal, by |J·v| ≤ 0.18 for a
        // unit direction at its edges and less nearer its middle.
        let k = Intrinsics::from_vertical_fov(64, 48, 60.0);
        let board = level(|u, _| match ((u as f32 - k.cx) / k.fx * 2.0).abs() < 0.5 {
            true => 2.0,
            false => 0.0,
        });
        let assoc = Association {
            max_distance: 0.1,
            min_normal_cos: 0.9,
            balance: false,
            window: 0,
        };
        let facing = |direction: [f64; 6]| {
            let bar = 0.34;
            facing_information(
                &board,
                &board,
                &Pose::IDENTITY,
                &assoc,
                (direction, 2.0),
                bar,
            )
        };
        // Turned by a about the vertical, and moved by -(a × centre):
        // scaled by the range, (2a, -2a) of unit length.
        let a = 0.5_f64.sqrt();
        let carried = facing([0.0, a, 0.0, -a, 0.0, 0.0]);
        // At most the mean of (a·x/2)² over the board's points, x within
        // ±0.5 m (its edge columns have no normal): 50 times the bar a
        // pose found after a loss is held to, where every row's |J·v| is
        // under 0.18 and none reached a bar on |J·v| itself.
        let most = 0.125 * 0.25 / 3.0;
        assert!(
            carried > 5e-3 && carried <= most,
            "{carried} against {most}"
        );
        // Sliding along the board is still pinned by none of it.
        assert_eq!(facing([0.0, 0.0, 0.0, 1.0, 0.0, 0.0]), 0.0);
    }

    #[test]
    fn block_equations_leave_out_the_information_the_noise_of_normals_makes_up() {
        // A plane 2 m away, seen through a map whose depth is off by up to
        // ±4 mm, pixel by pixel (normals a few degrees off); and a bumpy
        // surface, whose waves pin every motion along it.
        let noise = |u: u32, v: u32| {
            let h = (u.wrapping_mul(73_856_093) ^ v.wrapping_mul(19_349_663)) % 1000;
            (h as f32 / 1000.0 - 0.5) * 0.008
        };
        let bumps =
            |u: u32, v: u32| 2.0 + 0.1 * (u as f32 / 4.0).sin() + 0.1 * (v as f32 / 4.0).sin();
        let assoc = Association {
            max_distance: 0.1,
            min_normal_cos: 0.5,
            balance: false,
            window: 0,
        };
        let conditioning = |frame: &Level, model: &Level| {
            let pixels = equations(frame, model, &Pose::IDENTITY, &assoc);
            let blocks = block_equations(frame, model, &Pose::IDENTITY, &assoc, 2, 2);
            assert!(
                blocks.inliers * 3 < pixels.inliers,
                "one pixel in four counts"
            );
            (pixels.conditioning(), blocks.conditioning())
        };
        let (pixels, blocks) = conditioning(&level(|_, _| 2.0), &level(|u, v| 2.0 + noise(u, v)));
        assert!(blocks < pixels / 4.0, "{blocks} against {pixels}");
        // What the shape pins is kept.
        let (shape, shape_blocks) = conditioning(&level(bumps), &level(bumps));
        assert!(
            (shape_blocks / shape - 1.0).abs() < 0.25,
            "{shape_blocks} against {shape}"
        );
        assert!(blocks < shape / 20.0, "{blocks} against {shape}");
    }

    #[test]
    fn agreement_tells_unseen_from_contradicted() {
        let frame = level(|_, _| 2.0);
        let at = |model: &Level| agreement(&frame, model, &Pose::IDENTITY, 0.03);
        // The map has seen the left half only: the right half contradicts nothing.
        let half = at(&level(|u, _| if u < 32 { 2.0 } else { 0.0 }));
        assert!((half.overlap - 0.5).abs() < 0.05, "{half:?}");
        assert!(
            half.on_surface > 0.99 && half.contradicted < 0.01,
            "{half:?}"
        );
        // The map has a surface 0.5 m nearer over the left quarter: the
        // frame sees through it there.
        let through = at(&level(|u, _| if u < 16 { 1.5 } else { 2.0 }));
        assert!((through.contradicted - 0.25).abs() < 0.05, "{through:?}");
        assert!((through.on_surface - 0.75).abs() < 0.05, "{through:?}");
        assert!((through.overlap - 0.75).abs() < 0.05, "{through:?}");
    }
}
