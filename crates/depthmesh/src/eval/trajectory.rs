//! Trajectory accuracy: absolute trajectory error (ATE), raw and after a
//! rigid alignment, and relative pose error (RPE) between consecutive
//! matched poses, as the TUM RGB-D benchmark defines them.

use crate::camera::Pose;
use crate::error::{Error, Result};
use crate::linalg::horn;
use glam::{DMat3, DQuat, DVec3};

/// How an estimated trajectory compares with a reference.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrajectoryError {
    /// Estimated poses with a reference pose within the time tolerance.
    pub matched: usize,
    /// RMS distance between matched camera centres, as estimated (metres).
    pub ate_rmse: f64,
    /// Largest such distance (metres).
    pub ate_max: f64,
    /// RMS distance after the rigid motion that best aligns the estimate
    /// with the reference (Horn's method, no scale).
    pub ate_rmse_aligned: f64,
    /// RMS translation error of the motion between consecutive matched
    /// poses (metres); 0 with fewer than two matches.
    pub rpe_translation: f64,
    /// RMS rotation error of that motion (degrees).
    pub rpe_rotation_degrees: f64,
}

fn to_f64(p: &Pose) -> (DMat3, DVec3) {
    (p.rotation.as_dmat3(), p.translation.as_dvec3())
}

/// Compares `estimate` with `reference` (both `(timestamp, pose)`): each
/// estimated pose is matched with the reference pose nearest in time, if
/// within `max_dt` seconds. An error when nothing matches.
pub fn trajectory_error(
    estimate: &[(f64, Pose)],
    reference: &[(f64, Pose)],
    max_dt: f64,
) -> Result<TrajectoryError> {
    let mut sorted: Vec<&(f64, Pose)> = reference.iter().collect();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    let pairs: Vec<(Pose, Pose)> = estimate
        .iter()
        .filter_map(|(t, e)| {
            let i = sorted.partition_point(|r| r.0 < *t);
            let nearest = [i.checked_sub(1), Some(i)]
                .into_iter()
                .flatten()
                .filter_map(|j| sorted.get(j))
                .min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()))?;
            ((nearest.0 - t).abs() <= max_dt).then_some((*e, nearest.1))
        })
        .collect();
    if pairs.is_empty() {
        return Err(Error::parameter(
            "trajectories",
            format!("no estimated pose has a reference pose within {max_dt} s"),
        ));
    }
    let n = pairs.len() as f64;
    let centres: Vec<(DVec3, DVec3)> = pairs
        .iter()
        .map(|(e, r)| (to_f64(e).1, to_f64(r).1))
        .collect();
    let distances = centres.iter().map(|(e, r)| (*e - *r).length());
    let (sum2, max) = distances.fold((0.0, 0.0f64), |(s, m), d| (s + d * d, m.max(d)));
    let (rotation, translation) = horn(centres.iter().copied());
    let aligned2: f64 = centres
        .iter()
        .map(|(e, r)| (rotation * *e + translation - *r).length_squared())
        .sum();
    let (mut rpe_t, mut rpe_r) = (0.0, 0.0);
    for w in pairs.windows(2) {
        let (e0, e1) = (to_f64(&w[0].0), to_f64(&w[1].0));
        let (r0, r1) = (to_f64(&w[0].1), to_f64(&w[1].1));
        // Motion from one pose to the next, in the first camera's axes.
        let motion = |a: (DMat3, DVec3), b: (DMat3, DVec3)| {
            (a.0.transpose() * b.0, a.0.transpose() * (b.1 - a.1))
        };
        let (me, mr) = (motion(e0, e1), motion(r0, r1));
        let error_rotation = mr.0.transpose() * me.0;
        let error_translation = mr.0.transpose() * (me.1 - mr.1);
        rpe_t += error_translation.length_squared();
        let q = DQuat::from_mat3(&error_rotation);
        rpe_r += (2.0 * q.xyz().length().min(1.0).asin())
            .to_degrees()
            .powi(2);
    }
    let steps = (pairs.len() - 1).max(1) as f64;
    Ok(TrajectoryError {
        matched: pairs.len(),
        ate_rmse: (sum2 / n).sqrt(),
        ate_max: max,
        ate_rmse_aligned: (aligned2 / n).sqrt(),
        rpe_translation: (rpe_t / steps).sqrt(),
        rpe_rotation_degrees: (rpe_r / steps).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Mat3, Quat, Vec3};

    fn path(n: usize) -> Vec<(f64, Pose)> {
        (0..n)
            .map(|i| {
                let a = i as f32 * 0.1;
                let pose = Pose::look_at(
                    Vec3::new(2.0 * a.cos(), 1.0 + 0.1 * a, 2.0 * a.sin()),
                    Vec3::ZERO,
                    Vec3::Y,
                );
                (i as f64, pose)
            })
            .collect()
    }

    #[test]
    fn identical_trajectories_have_no_error() {
        let p = path(20);
        let e = trajectory_error(&p, &p, 0.02).unwrap();
        assert_eq!(e.matched, 20);
        assert!(e.ate_rmse < 1e-9 && e.ate_rmse_aligned < 1e-6 && e.rpe_translation < 1e-6);
    }

    #[test]
    fn a_rigidly_moved_trajectory_aligns_exactly() {
        let p = path(30);
        let motion = Pose::new(
            Mat3::from_quat(Quat::from_euler(glam::EulerRot::XYZ, 0.3, -0.5, 0.2)),
            Vec3::new(0.5, -1.0, 2.0),
        );
        let moved: Vec<(f64, Pose)> = p.iter().map(|(t, q)| (*t, motion.compose(q))).collect();
        let e = trajectory_error(&moved, &p, 0.02).unwrap();
        assert!(e.ate_rmse > 0.5, "{e:?}");
        assert!(e.ate_rmse_aligned < 1e-5, "{e:?}");
        // Relative motion does not see a global transform.
        assert!(
            e.rpe_translation < 1e-5 && e.rpe_rotation_degrees < 1e-2,
            "{e:?}"
        );
    }

    #[test]
    fn a_constant_offset_is_ate_and_a_step_is_rpe() {
        let p = path(10);
        let mut shifted = p.clone();
        for (i, (_, pose)) in shifted.iter_mut().enumerate() {
            if i >= 5 {
                pose.translation.x += 0.03;
            }
        }
        let e = trajectory_error(&shifted, &p, 0.02).unwrap();
        assert!((e.ate_max - 0.03).abs() < 1e-6);
        assert!((e.ate_rmse - (0.5f64 * 0.03 * 0.03).sqrt()).abs() < 1e-6);
        // One of nine steps is off by 3 cm.
        assert!((e.rpe_translation - (0.03f64 * 0.03 / 9.0).sqrt()).abs() < 1e-6);
    }

    #[test]
    fn poses_are_matched_by_nearest_time_within_the_tolerance() {
        let p = path(5);
        let late: Vec<(f64, Pose)> = p.iter().map(|(t, q)| (t + 0.01, *q)).collect();
        assert_eq!(trajectory_error(&late, &p, 0.02).unwrap().matched, 5);
        let e = trajectory_error(&late, &p, 0.005).unwrap_err();
        assert!(e.to_string().contains("no estimated pose"));
    }
}
