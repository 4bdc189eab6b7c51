//! The degeneracy-aware ICP update of Zhang, Kaess and Singh (ICRA 2016,
//! "On degeneracy of optimization-based state estimation problems"): the
//! pose follows the data only along the eigen-directions they constrain
//! well; along the others it keeps the prediction it started from (the
//! constant-velocity motion model).
//!
//! Unlike the paper, which drops the weak directions from every update,
//! ICP here iterates on all directions but the numerically singular ones
//! and removes the weak part of the motion once, from the system at the
//! pose found: while far from it (a first frame with no motion model), a
//! direction can look weak only because the frame does not overlap the
//! model's structure yet, and dropping it then stops ICP short.
//!
//! A floor with a table, a long wall or a corridor constrains some motions
//! well and others barely; solving them all lets noise push the pose along
//! the weak ones, refusing the frame throws away a view that pins down
//! most of the pose.
//!
//! Weak is relative (a small eigenvalue of the per-inlier system), but the
//! prediction is not exact either: a constant velocity that is slightly
//! off along a weak direction is never corrected if that direction always
//! keeps it, and the error grows frame after frame (a floor with one small
//! box, orbited: 17 cm in 25 frames). So along a weak direction the data
//! and the prediction are weighed by their variances, as a Kalman update
//! would: the data's is the noise over the information the inliers carry
//! along it (`noise² / (λ·n)`), the prediction's the motion model's
//! per-frame error (`motion_sigma²`). A plane's in-plane motion (λ ≈ 0)
//! still keeps the prediction; a direction that many points pin down
//! weakly each follows the data in part.

use super::icp::Equations;
use crate::linalg::symmetric_eigen;

/// Names of the six motion axes in the camera frame, in the order of
/// [`Weak::axes`]' bits: rotations about x, y, z, translations
/// along x, y, z.
pub const AXES: [&str; 6] = ["rx", "ry", "rz", "tx", "ty", "tz"];

/// The eigen-directions of one ICP system (of the per-inlier,
/// range-scaled matrix of [`Equations::conditioning`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Directions {
    values: [f64; 6],
    vectors: [[f64; 6]; 6],
    b: [f64; 6],
    scale: [f64; 6],
    /// Noise of one inlier's residual (metres).
    noise: f64,
    /// Inliers of the system.
    inliers: f64,
}

/// The noise of a residual is taken as at least this (metres): a close,
/// smoothed view can fit its model to well under a millimetre, while the
/// model's own error is not in that figure.
const NOISE_FLOOR: f64 = 1e-3;

/// Directions where the prediction weighs more than the data.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Weak {
    /// How many eigen-directions (0 to 6).
    pub count: u8,
    /// For each, the bit (see [`AXES`]) of the axis it moves most along; a
    /// bit can stand for several directions.
    pub axes: u8,
}

impl Directions {
    /// The eigen-directions of `eq`; `None` without inliers.
    pub fn of(eq: &Equations) -> Option<Directions> {
        let (a, b, scale) = eq.scaled()?;
        let (values, vectors) = symmetric_eigen(&a);
        Some(Directions {
            values,
            vectors,
            b,
            scale,
            noise: eq.rms().max(NOISE_FLOOR),
            inliers: eq.inliers as f64,
        })
    }

    /// The weakest eigen-direction, as a unit vector of the range-scaled
    /// system (rotation × range, then translation), and the range that
    /// scales its rotations.
    pub fn weakest(&self) -> ([f64; 6], f64) {
        (self.vectors[0], 1.0 / self.scale[0])
    }

    /// The share of the data's estimate kept along a direction of
    /// eigenvalue `value`, against a prediction of standard deviation
    /// `motion_sigma` (both in metres of the scaled system): 1 where the
    /// direction is not weak (`value` at least `min_eigenvalue`).
    fn data_weight(&self, value: f64, min_eigenvalue: f64, motion_sigma: f64) -> f64 {
        if value >= min_eigenvalue {
            return 1.0;
        }
        let information = value.max(0.0) * self.inliers;
        let data_variance = self.noise * self.noise;
        let prior = motion_sigma * motion_sigma;
        // w = σp² / (σp² + σd²) with σd² = noise² / information.
        prior * information / (prior * information + data_variance)
    }

    /// The update (rotation as a scaled axis, translation) solving the
    /// system along the directions whose eigenvalue is at least `floor`,
    /// zero along the others.
    pub fn solve(&self, floor: f64) -> ([f64; 3], [f64; 3]) {
        let mut y = [0.0; 6];
        for (&value, v) in self.values.iter().zip(&self.vectors) {
            // NaN fails the comparison too.
            if value.partial_cmp(&floor.max(0.0)) != Some(std::cmp::Ordering::Greater) {
                continue;
            }
            // The component of the solution of a·y = -b along v.
            let along = -dot(v, &self.b) / value;
            for (y, v) in y.iter_mut().zip(v) {
                *y += along * v;
            }
        }
        let x: [f64; 6] = std::array::from_fn(|i| y[i] * self.scale[i]);
        ([x[0], x[1], x[2]], [x[3], x[4], x[5]])
    }

    /// The directions with an eigenvalue below `min_eigenvalue` along
    /// which the data weigh less than a prediction of standard deviation
    /// `motion_sigma`.
    pub fn weak(&self, min_eigenvalue: f64, motion_sigma: f64) -> Weak {
        let mut weak = Weak::default();
        for (&value, v) in self.values.iter().zip(&self.vectors) {
            if self.data_weight(value, min_eigenvalue, motion_sigma) >= 0.5 {
                continue;
            }
            weak.count += 1;
            let axis = (0..6)
                .max_by(|&i, &j| v[i].abs().total_cmp(&v[j].abs()))
                .unwrap_or(0);
            weak.axes |= 1 << axis;
        }
        weak
    }

    /// `motion` (rotation as a scaled axis, translation, away from the
    /// prediction) with its components along the directions with an
    /// eigenvalue below `min_eigenvalue` weighed against the prediction of
    /// standard deviation `motion_sigma` (0: dropped).
    pub fn without_weak(
        &self,
        motion: ([f64; 3], [f64; 3]),
        min_eigenvalue: f64,
        motion_sigma: f64,
    ) -> ([f64; 3], [f64; 3]) {
        let x = [
            motion.0[0],
            motion.0[1],
            motion.0[2],
            motion.1[0],
            motion.1[1],
            motion.1[2],
        ];
        let mut y: [f64; 6] = std::array::from_fn(|i| x[i] / self.scale[i]);
        for (&value, v) in self.values.iter().zip(&self.vectors) {
            let dropped = 1.0 - self.data_weight(value, min_eigenvalue, motion_sigma);
            if dropped == 0.0 {
                continue;
            }
            let along = dropped * dot(v, &y);
            for (y, v) in y.iter_mut().zip(v) {
                *y -= along * v;
            }
        }
        let x: [f64; 6] = std::array::from_fn(|i| y[i] * self.scale[i]);
        ([x[0], x[1], x[2]], [x[3], x[4], x[5]])
    }
}

fn dot(a: &[f64; 6], b: &[f64; 6]) -> f64 {
    a.iter().zip(b).map(|(a, b)| a * b).sum()
}

/// `mask` (bits of [`AXES`]) as axis names joined by `|`, or `-` for none:
/// the form for a CSV column.
pub fn axes_label(mask: u8) -> String {
    let names: Vec<&str> = AXES
        .iter()
        .enumerate()
        .filter(|(i, _)| mask & (1 << i) != 0)
        .map(|(_, n)| *n)
        .collect();
    if names.is_empty() {
        "-".into()
    } else {
        names.join("|")
    }
}
