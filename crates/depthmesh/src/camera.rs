//! Pinhole intrinsics and camera-to-world poses (OpenCV axes: x right, y down, z forward).

use crate::error::{Error, Result};
use glam::{Mat3, Quat, Vec2, Vec3};

/// Narrowest field of view a camera model may have, along either axis.
pub const MIN_FOV_DEGREES: f32 = 1.0;
/// Widest field of view a pinhole model may have (a pinhole cannot see 180°).
pub const MAX_FOV_DEGREES: f32 = 170.0;

/// A pinhole camera model. Pixel `(u, v)` has its centre at integer coordinates,
/// so a 640-wide image centred on the optical axis has `cx = 319.5`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Intrinsics {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, in pixels.
    pub fx: f32,
    /// Focal length along y, in pixels.
    pub fy: f32,
    /// Principal point x, in pixels.
    pub cx: f32,
    /// Principal point y, in pixels.
    pub cy: f32,
}

impl Intrinsics {
    /// A centred camera with square pixels and the given vertical field of view.
    pub fn from_vertical_fov(width: u32, height: u32, fov_degrees: f32) -> Self {
        let fy = 0.5 * height as f32 / (0.5 * fov_degrees.to_radians()).tan();
        Intrinsics {
            width,
            height,
            fx: fy,
            fy,
            cx: (width as f32 - 1.0) * 0.5,
            cy: (height as f32 - 1.0) * 0.5,
        }
    }

    /// The Kinect-class sensor of the MABDI thesis: 640×480, 60° vertical field of view.
    pub fn kinect() -> Self {
        Self::from_vertical_fov(640, 480, 60.0)
    }

    /// Rejects models that cannot image anything (zero size, non-positive
    /// focal length) or that are larger than the rasterizer's fixed-point
    /// range covers (4096 pixels a side).
    pub fn validate(&self) -> Result<()> {
        if self.width == 0 || self.height == 0 {
            return Err(Error::parameter(
                "intrinsics",
                format!("image size {}×{} is empty", self.width, self.height),
            ));
        }
        if self.width > 4096 || self.height > 4096 {
            return Err(Error::parameter(
                "intrinsics",
                format!(
                    "image size {}×{} exceeds 4096 pixels a side",
                    self.width, self.height
                ),
            ));
        }
        let finite = [self.fx, self.fy, self.cx, self.cy]
            .iter()
            .all(|v| v.is_finite());
        if !finite || self.fx <= 0.0 || self.fy <= 0.0 {
            return Err(Error::parameter(
                "intrinsics",
                format!(
                    "focal lengths must be positive and finite (fx = {}, fy = {})",
                    self.fx, self.fy
                ),
            ));
        }
        // Finite but absurd models (fx = 1e-30 spreads every pixel over the
        // whole world) would make fusion and ray casting run for hours.
        for (axis, size, f) in [("x", self.width, self.fx), ("y", self.height, self.fy)] {
            let fov = 2.0 * (0.5 * size as f32 / f).atan().to_degrees();
            if !(MIN_FOV_DEGREES..=MAX_FOV_DEGREES).contains(&fov) {
                return Err(Error::parameter(
                    "intrinsics",
                    format!(
                        "f{axis} = {f} gives a field of view of {fov:.3}° over {size} pixels; \
                         a depth camera's is between {MIN_FOV_DEGREES}° and {MAX_FOV_DEGREES}°"
                    ),
                ));
            }
        }
        let inside = |c: f32, size: u32| (-0.5..=size as f32 - 0.5).contains(&c);
        if !inside(self.cx, self.width) || !inside(self.cy, self.height) {
            return Err(Error::parameter(
                "intrinsics",
                format!(
                    "principal point ({}, {}) lies outside the {}×{} image",
                    self.cx, self.cy, self.width, self.height
                ),
            ));
        }
        Ok(())
    }

    /// Number of pixels.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Projects a camera-space point to pixel coordinates; `None` behind the camera.
    pub fn project(&self, p: Vec3) -> Option<Vec2> {
        (p.z > 0.0).then(|| Vec2::new(self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }

    /// The camera-space point at pixel `(u, v)` with depth `z` along the optical axis.
    pub fn back_project(&self, u: f32, v: f32, z: f32) -> Vec3 {
        Vec3::new((u - self.cx) / self.fx * z, (v - self.cy) / self.fy * z, z)
    }
}

/// A rigid camera-to-world transform: `world = rotation * camera + translation`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Rotation from camera axes to world axes.
    pub rotation: Mat3,
    /// Camera centre in world coordinates.
    pub translation: Vec3,
}

impl Default for Pose {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Pose {
    /// The camera at the world origin with camera axes equal to world axes.
    pub const IDENTITY: Pose = Pose {
        rotation: Mat3::IDENTITY,
        translation: Vec3::ZERO,
    };

    /// A pose from a rotation and the camera centre.
    pub fn new(rotation: Mat3, translation: Vec3) -> Self {
        Pose {
            rotation,
            translation,
        }
    }

    /// A camera at `eye` looking at `target`, with image "up" (−y in camera axes)
    /// as close as possible to `up` in world coordinates.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3) -> Self {
        let z = (target - eye).normalize();
        let x = z.cross(up).normalize();
        let y = z.cross(x);
        Pose::new(Mat3::from_cols(x, y, z), eye)
    }

    /// From a unit quaternion (camera-to-world rotation) and a translation, as in TUM files.
    pub fn from_quat(q: Quat, translation: Vec3) -> Self {
        Pose::new(Mat3::from_quat(q.normalize()), translation)
    }

    /// The rotation as a unit quaternion.
    pub fn quat(&self) -> Quat {
        Quat::from_mat3(&self.rotation).normalize()
    }

    /// Maps a camera-space point to world space.
    pub fn transform_point(&self, p: Vec3) -> Vec3 {
        self.rotation * p + self.translation
    }

    /// Maps a camera-space direction to world space.
    pub fn transform_vector(&self, v: Vec3) -> Vec3 {
        self.rotation * v
    }

    /// The world-to-camera transform, as a pose.
    pub fn inverse(&self) -> Pose {
        let rt = self.rotation.transpose();
        Pose::new(rt, -(rt * self.translation))
    }

    /// `self ∘ other`: apply `other`, then `self`.
    pub fn compose(&self, other: &Pose) -> Pose {
        Pose::new(
            self.rotation * other.rotation,
            self.rotation * other.translation + self.translation,
        )
    }

    /// This motion made `n` times over (at least once): a constant velocity
    /// carried across `n` frame intervals.
    pub fn power(&self, n: usize) -> Pose {
        (1..n.max(1)).fold(*self, |p, _| p.compose(self))
    }

    /// The motion that, made `n` times over, is this one: a constant
    /// velocity measured across `n` frame intervals, one interval's worth.
    /// The turn is split evenly about its axis, and the step solves
    /// `(I + R + … + Rⁿ⁻¹) t = translation` for the split turn `R`, so the
    /// root's [`Pose::power`] of `n` gives back `self` on a curve as on a line.
    pub fn root(&self, n: usize) -> Pose {
        if n <= 1 {
            return *self;
        }
        let turn = Mat3::from_quat(Quat::from_scaled_axis(
            self.quat().to_scaled_axis() / n as f32,
        ));
        let mut sum = Mat3::IDENTITY;
        let mut power = Mat3::IDENTITY;
        for _ in 1..n {
            power = turn * power;
            sum += power;
        }
        // The sum is singular only for a split turn of a whole number of
        // n-ths of a revolution, far beyond any frame's; the plain share
        // is the answer as the turn goes to nothing.
        let step = if sum.determinant().abs() > 1e-6 {
            sum.inverse() * self.translation
        } else {
            self.translation / n as f32
        };
        Pose::new(turn, step)
    }

    /// The angle of the rotation in radians (0..=π), accurate for small
    /// angles too (from the quaternion's vector part, not its cosine).
    pub fn rotation_angle(&self) -> f32 {
        2.0 * self.quat().xyz().length().min(1.0).asin()
    }

    /// The optical axis (camera +z) in world coordinates.
    pub fn forward(&self) -> Vec3 {
        self.rotation.z_axis
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projection_round_trip() {
        let k = Intrinsics::kinect();
        assert!((k.fy - 415.692).abs() < 1e-3);
        for &(u, v, z) in &[(0.0, 0.0, 0.8), (319.5, 239.5, 2.0), (639.0, 479.0, 4.0)] {
            let p = k.back_project(u, v, z);
            let q = k.project(p).unwrap();
            assert!((q.x - u).abs() < 1e-3 && (q.y - v).abs() < 1e-3);
        }
        assert!(k.project(Vec3::new(0.0, 0.0, -1.0)).is_none());
    }

    #[test]
    fn pose_round_trip() {
        let pose = Pose::look_at(Vec3::new(3.0, 1.5, -2.0), Vec3::new(0.0, 0.5, 0.0), Vec3::Y);
        let p = Vec3::new(0.3, -0.2, 1.7);
        let w = pose.transform_point(p);
        let back = pose.inverse().transform_point(w);
        assert!((back - p).length() < 1e-5);
        let again = Pose::from_quat(pose.quat(), pose.translation);
        assert!((again.transform_point(p) - w).length() < 1e-5);
        // Looking at the target: it lies on the optical axis, in front.
        let t = pose.inverse().transform_point(Vec3::new(0.0, 0.5, 0.0));
        assert!(t.x.abs() < 1e-5 && t.y.abs() < 1e-5 && t.z > 0.0);
        // World up appears as image up (negative camera y).
        let up = pose.inverse().transform_vector(Vec3::Y);
        assert!(up.y < 0.0);
    }

    #[test]
    fn a_root_made_n_times_over_gives_the_motion_back() {
        let motion = Pose::new(
            Mat3::from_quat(Quat::from_scaled_axis(Vec3::new(0.02, -0.31, 0.05))),
            Vec3::new(0.12, -0.03, 0.27),
        );
        for n in [1, 2, 3, 7, 15] {
            let root = motion.root(n);
            let again = root.power(n);
            assert!(
                (again.translation - motion.translation).length() < 1e-5,
                "n = {n}"
            );
            assert!(
                again.inverse().compose(&motion).rotation_angle() < 1e-5,
                "n = {n}"
            );
            // An even share of the turn, not a turn put in one step.
            let share = motion.rotation_angle() / n as f32;
            assert!((root.rotation_angle() - share).abs() < 1e-5, "n = {n}");
        }
        // No turn: the step is the plain share.
        let line = Pose::new(Mat3::IDENTITY, Vec3::new(0.3, 0.0, -0.6));
        assert!((line.root(3).translation - Vec3::new(0.1, 0.0, -0.2)).length() < 1e-6);
    }

    #[test]
    fn rejects_empty_intrinsics() {
        let mut k = Intrinsics::kinect();
        k.width = 0;
        assert!(k.validate().is_err());
    }
}
