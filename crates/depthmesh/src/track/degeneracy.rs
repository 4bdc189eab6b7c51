//! The degeneracy-aware ICP update, after Zhang, Kaess and Singh (ICRA
//! 2016, "On degeneracy of optimization-based state estimation problems"):
//! the pose follows the data along the eigen-directions they constrain
//! well and keeps the prediction it started from (the constant-velocity
//! motion model) along the others.
//!
//! Unlike the paper's hard cut, every ICP update combines the two by their
//! information: the prediction is a prior that counts as much as a
//! direction constrained with the tracker's `weak_conditioning`, so a
//! direction constrained far less goes back to the prediction, one
//! constrained about as much moves part of the way, and the prior fades
//! out along well-constrained ones ([`Directions::solve`]). With a hard cut
//! the weak part followed the prediction alone, and the constant-velocity
//! model then carried its error on from frame to frame; with the prior
//! the data still pull it back a little every frame.
//!
//! A floor with a table, a long wall or a corridor constrains some motions
//! well and others barely; solving them all lets noise push the pose along
//! the weak ones, refusing the frame throws away a view that pins down
//! most of the pose.

use super::icp::Equations;
use crate::linalg::symmetric_eigen;

/// Names of the six motion axes in the camera frame, in the order of
/// [`Update::weak_axes`]'s bits: rotations about x, y, z, translations
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
}

/// Directions left to the prediction.
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
        })
    }

    /// The update (rotation as a scaled axis, translation) that minimises
    /// the linearised error plus `prior` times the squared range-scaled
    /// distance from the prediction, which lies `-offset` from the current
    /// estimate (`offset`: the motion taken beyond the prediction so far):
    /// `(A + prior·I)·y = −b − prior·offset` on the scaled system. Along a
    /// direction whose eigenvalue is well above `prior` the data decide;
    /// well below, the estimate goes back to the prediction; in between, each
    /// in proportion to its information; from [`PRIOR_FADE`] times `prior`
    /// on, the prior fades out ([`fade`]). Directions whose eigenvalue plus
    /// `prior` is not above `floor` are left alone (zero update): with no
    /// prediction (`prior` 0), a plane's in-plane motion is numerically
    /// singular.
    pub fn solve(
        &self,
        floor: f64,
        prior: f64,
        offset: ([f64; 3], [f64; 3]),
    ) -> ([f64; 3], [f64; 3]) {
        let d = self.scaled_motion(offset);
        let mut y = [0.0; 6];
        for (&value, v) in self.values.iter().zip(&self.vectors) {
            let prior = if prior > 0.0 {
                prior * fade(value / prior)
            } else {
                0.0
            };
            let information = value + prior;
            // NaN fails the comparison too.
            if information.partial_cmp(&floor.max(0.0)) != Some(std::cmp::Ordering::Greater) {
                continue;
            }
            // The component of the solution along v.
            let along = -(dot(v, &self.b) + prior * dot(v, &d)) / information;
            for (y, v) in y.iter_mut().zip(v) {
                *y += along * v;
            }
        }
        self.unscaled_motion(y)
    }

    /// A motion in the scaled coordinates of the system.
    fn scaled_motion(&self, (omega, t): ([f64; 3], [f64; 3])) -> [f64; 6] {
        let x = [omega[0], omega[1], omega[2], t[0], t[1], t[2]];
        std::array::from_fn(|i| x[i] / self.scale[i])
    }

    /// A motion from the scaled coordinates of the system.
    fn unscaled_motion(&self, y: [f64; 6]) -> ([f64; 3], [f64; 3]) {
        let x: [f64; 6] = std::array::from_fn(|i| y[i] * self.scale[i]);
        ([x[0], x[1], x[2]], [x[3], x[4], x[5]])
    }

    /// The directions with an eigenvalue below `min_eigenvalue`.
    pub fn weak(&self, min_eigenvalue: f64) -> Weak {
        let mut weak = Weak::default();
        for (&value, v) in self.values.iter().zip(&self.vectors) {
            if value >= min_eigenvalue {
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
}

/// Directions constrained this many times more than the prior gets from
/// [`Directions::solve`] get no prior at all; in between, it fades.
const PRIOR_FADE: f64 = 4.0;

/// The share of the prior a direction with `ratio` times its information
/// gets: all of it up to 1, none from [`PRIOR_FADE`], linear in between.
/// Along well-constrained directions a prior would only hide a jump the
/// data see: a camera that jumped half a metre in a room (its view
/// constrained with 5× the prior) was held short of its pose, at a wrong
/// one that still matched a third of its points.
fn fade(ratio: f64) -> f64 {
    ((PRIOR_FADE - ratio) / (PRIOR_FADE - 1.0)).clamp(0.0, 1.0)
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
