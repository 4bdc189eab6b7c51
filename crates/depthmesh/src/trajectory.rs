//! TUM trajectory files: one pose per line, `timestamp tx ty tz qx qy qz qw`,
//! camera-to-world, metres and seconds; `#` comments and blank lines allowed.

use crate::camera::Pose;
use crate::error::{Error, Result};
use glam::{Quat, Vec3};
use std::fmt::Write;
use std::path::Path;

/// How far from 1 a quaternion's norm may be: files written with four
/// decimals are off by ~1e-4, while a wrong column order or a typo is far off.
const QUAT_NORM_TOLERANCE: f64 = 1e-2;

/// The lines of a TUM-style text file that hold data, with their 1-based
/// numbers: blank lines and `#` comments are skipped.
pub(crate) fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, line)| (i + 1, line.trim()))
        .filter(|(_, line)| !line.is_empty() && !line.starts_with('#'))
}

/// Parses TUM trajectory `text`; `source` names the file in errors.
pub fn parse_tum(text: &str, source: &Path) -> Result<Vec<(f64, Pose)>> {
    let mut poses = Vec::new();
    for (number, line) in data_lines(text) {
        let fail = |message: String| Error::format(source, format!("line {number}: {message}"));
        let fields: Vec<&str> = line.split_whitespace().collect();
        if fields.len() != 8 {
            return Err(fail(format!(
                "expected 8 fields (timestamp tx ty tz qx qy qz qw), found {}",
                fields.len()
            )));
        }
        let mut v = [0.0f64; 8];
        for (value, field) in v.iter_mut().zip(&fields) {
            *value = field
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| fail(format!("\"{field}\" is not a finite number")))?;
        }
        let [t, tx, ty, tz, qx, qy, qz, qw] = v;
        let norm = (qx * qx + qy * qy + qz * qz + qw * qw).sqrt();
        if (norm - 1.0).abs() > QUAT_NORM_TOLERANCE {
            return Err(fail(format!(
                "quaternion (qx qy qz qw) has norm {norm}, expected a unit quaternion"
            )));
        }
        let q = Quat::from_xyzw(qx as f32, qy as f32, qz as f32, qw as f32);
        poses.push((
            t,
            Pose::from_quat(q, Vec3::new(tx as f32, ty as f32, tz as f32)),
        ));
    }
    Ok(poses)
}

/// Formats poses as a TUM file with a header comment: timestamps and
/// translations with 6 decimals, quaternions with 8.
pub fn format_tum(poses: &[(f64, Pose)]) -> String {
    let mut out = String::from("# timestamp tx ty tz qx qy qz qw\n");
    for (t, pose) in poses {
        let p = pose.translation;
        let q = pose.quat();
        // Writing to a String cannot fail.
        let _ = writeln!(
            out,
            "{t:.6} {:.6} {:.6} {:.6} {:.8} {:.8} {:.8} {:.8}",
            p.x, p.y, p.z, q.x, q.y, q.z, q.w
        );
    }
    out
}

/// Reads a TUM trajectory file.
pub fn read_tum(path: &Path) -> Result<Vec<(f64, Pose)>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse_tum(&text, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let poses: Vec<(f64, Pose)> = (0..20)
            .map(|i| {
                let a = i as f32 * 0.7;
                let eye = Vec3::new(3.0 * a.sin(), 1.0 + 0.05 * i as f32, 3.0 * a.cos());
                let pose = Pose::look_at(eye, Vec3::new(0.0, 0.5, 0.0), Vec3::Y);
                (1_305_031_102.175304 + i as f64 / 30.0, pose)
            })
            .collect();
        let text = format_tum(&poses);
        let back = parse_tum(&text, Path::new("t.txt")).unwrap();
        assert_eq!(back.len(), poses.len());
        for ((t0, p0), (t1, p1)) in poses.iter().zip(&back) {
            assert!((t0 - t1).abs() < 1e-6);
            assert!(p0.translation.abs_diff_eq(p1.translation, 1e-5));
            assert!(p0.rotation.abs_diff_eq(p1.rotation, 1e-6));
        }
    }

    #[test]
    fn skips_comments_and_blank_lines() {
        let text = "# tum\n\n  1.0 0 0 0 0 0 0 1\n# more\n2.0 1 2 3 0 0 0.7071068 0.7071068\n";
        let poses = parse_tum(text, Path::new("t.txt")).unwrap();
        assert_eq!(poses.len(), 2);
        assert_eq!(poses[1].1.translation, Vec3::new(1.0, 2.0, 3.0));
        // 90° about z maps camera x onto world y.
        assert!(poses[1]
            .1
            .transform_vector(Vec3::X)
            .abs_diff_eq(Vec3::Y, 1e-6));
    }

    #[test]
    fn errors_name_file_and_line() {
        let cases = [
            ("1 0 0 0 0 0 0\n", "expected 8 fields"),
            ("1 0 0 0 0 0 0 1 9\n", "found 9"),
            ("1 0 x 0 0 0 0 1\n", "\"x\" is not a finite number"),
            ("1 0 0 nan 0 0 0 1\n", "\"nan\""),
            ("1 0 0 0 0 0 0 0\n", "norm 0"),
            ("1 0 0 0 0 0 0 2\n", "norm 2"),
        ];
        for (body, expected) in cases {
            let text = format!("# header\n0 0 0 0 0 0 0 1\n{body}");
            let e = parse_tum(&text, Path::new("gt.txt"))
                .unwrap_err()
                .to_string();
            assert!(
                e.starts_with("gt.txt: line 3: ") && e.contains(expected),
                "{e}"
            );
        }
    }

    #[test]
    fn missing_file_is_an_io_error() {
        let e = read_tum(Path::new("/nonexistent/traj.txt")).unwrap_err();
        assert!(matches!(e, Error::Io { .. }));
    }
}
