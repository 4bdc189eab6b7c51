//! The 7-Scenes "frames folder": `frame-NNNNNN.depth.png` (16-bit millimetres),
//! `frame-NNNNNN.color.jpg` (or `.color.png`), `frame-NNNNNN.pose.txt` (4×4
//! camera-to-world) and `camera-intrinsics.txt` (3×3 K).

use super::{choose_intrinsics, parse_numbers, DatasetOptions, FrameFiles, FramePose, Index};
use crate::camera::Pose;
use crate::error::{Error, Result};
use glam::{DMat3, DVec3};
use std::collections::HashSet;
use std::path::Path;

/// How far `RᵀR` may be from the identity: poses are written with about eight
/// digits, while a scaled or sheared matrix (a wrong file) is far off.
const ORTHONORMAL_TOLERANCE: f64 = 1e-3;

/// Lists the frames of the frames folder `dir`; `None` when it holds no
/// `frame-N.depth.png`, so the caller can say which layouts it looked for.
pub(super) fn index(dir: &Path, options: &DatasetOptions) -> Result<Option<Index>> {
    let mut names = HashSet::new();
    for entry in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        if let Ok(name) = entry.file_name().into_string() {
            names.insert(name);
        }
    }
    // Stems are `frame-N` as spelled on disk, so any zero padding works.
    let mut stems: Vec<(usize, &str)> = names
        .iter()
        .filter_map(|name| {
            let stem = name.strip_suffix(".depth.png")?;
            let digits = stem.strip_prefix("frame-")?;
            if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
                return None;
            }
            Some((digits.parse().ok()?, stem))
        })
        .collect();
    if stems.is_empty() {
        return Ok(None);
    }
    stems.sort_unstable();
    if let Some(pair) = stems.windows(2).find(|pair| pair[0].0 == pair[1].0) {
        return Err(Error::format(
            dir.join(format!("{}.depth.png", pair[1].1)),
            format!("has the same frame number as {}.depth.png", pair[0].1),
        ));
    }

    // Poses and colour are all-or-nothing: a folder without any is fine, but
    // once some frames have them, a frame without one is a missing file.
    let any_has = |suffix: &str| {
        stems
            .iter()
            .any(|(_, stem)| names.contains(&format!("{stem}{suffix}")))
    };
    let has_poses = any_has(".pose.txt");
    let color_suffix = [".color.jpg", ".color.png"]
        .into_iter()
        .find(|suffix| any_has(suffix));
    let frames = stems
        .iter()
        .map(|&(number, stem)| FrameFiles {
            number,
            timestamp: number as f64,
            depth: dir.join(format!("{stem}.depth.png")),
            color: color_suffix.map(|suffix| dir.join(format!("{stem}{suffix}"))),
            pose: if has_poses {
                FramePose::File(dir.join(format!("{stem}.pose.txt")))
            } else {
                FramePose::Absent
            },
        })
        .collect();

    let intrinsics = choose_intrinsics(options, &dir.join("camera-intrinsics.txt"), None, || {
        format!("{} has no camera-intrinsics.txt", dir.display())
    })?;
    Ok(Some(Index {
        depth_units_per_metre: 1000.0,
        intrinsics,
        frames,
    }))
}

/// Reads a 7-Scenes pose file: a 4×4 camera-to-world matrix, row by row. The
/// bottom row and the rotation are checked so a transposed, scaled or wrong
/// file is an error naming it, not a silently distorted map.
pub(super) fn read_pose(path: &Path) -> Result<Pose> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let m = parse_numbers(&text).map_err(|message| Error::format(path, message))?;
    if m.len() != 16 {
        return Err(Error::format(
            path,
            format!(
                "expected a 4×4 matrix (16 numbers), found {} numbers",
                m.len()
            ),
        ));
    }
    let bottom = &m[12..16];
    if bottom
        .iter()
        .zip([0.0, 0.0, 0.0, 1.0])
        .any(|(a, b)| (a - b).abs() > 1e-6)
    {
        return Err(Error::format(
            path,
            format!("bottom row is {bottom:?}, expected [0, 0, 0, 1]"),
        ));
    }
    let rotation = DMat3::from_cols(
        DVec3::new(m[0], m[4], m[8]),
        DVec3::new(m[1], m[5], m[9]),
        DVec3::new(m[2], m[6], m[10]),
    );
    let deviation = (rotation.transpose() * rotation - DMat3::IDENTITY)
        .to_cols_array()
        .iter()
        .fold(0.0f64, |max, v| max.max(v.abs()));
    if deviation > ORTHONORMAL_TOLERANCE {
        return Err(Error::format(
            path,
            format!("the 3×3 rotation is not orthonormal (RᵀR differs from I by {deviation:.2e})"),
        ));
    }
    if rotation.determinant() < 0.0 {
        return Err(Error::format(
            path,
            "the 3×3 rotation is a reflection (determinant −1)",
        ));
    }
    Ok(Pose::new(
        rotation.as_mat3(),
        DVec3::new(m[3], m[7], m[11]).as_vec3(),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::scratch::ScratchDir;
    use crate::dataset::test_util::frames_folder;
    use crate::dataset::{Dataset, DatasetOptions, FrameRange, IntrinsicsSpec, Layout};
    use glam::{Mat3, Vec3};

    #[test]
    fn round_trip() {
        let dir = frames_folder("frames-round-trip", 3);
        let options = DatasetOptions {
            color: true,
            depth_max: 1.15,
            ..DatasetOptions::default()
        };
        let dataset = Dataset::open(dir.path(), &options).unwrap();
        assert_eq!(dataset.layout(), Layout::FramesFolder);
        assert_eq!(dataset.len(), 3);
        let k = dataset.intrinsics();
        assert_eq!(
            (k.width, k.height, k.fx, k.fy, k.cx, k.cy),
            (4, 3, 5.0, 5.0, 1.5, 1.0)
        );

        let frame = dataset.frame(1).unwrap();
        assert_eq!((frame.index, frame.timestamp), (1, 1.0));
        assert_eq!(&frame.depth.data[..3], &[0.0, 0.0, 1.1]);
        assert_eq!(frame.depth.valid_count(), 10);
        assert_eq!(frame.color.unwrap().data[5], [1, 0, 0]);
        let pose = frame.pose.unwrap();
        assert_eq!(pose.translation, Vec3::new(0.01, 0.0, 0.0));
        // Turned 90° about y, the camera looks along world +x.
        assert_eq!(pose.forward(), Vec3::X);
        assert_eq!(pose.rotation, Mat3::from_cols(-Vec3::Z, Vec3::Y, Vec3::X));
        // Frame 2 is at 1.2 m, beyond depth_max.
        assert_eq!(dataset.frame(2).unwrap().depth.valid_count(), 0);
        assert!(dataset.frame(3).is_err());

        let without_color = Dataset::open(dir.path(), &DatasetOptions::default()).unwrap();
        assert!(without_color.frame(0).unwrap().color.is_none());
    }

    #[test]
    fn selects_half_open_range_with_stride() {
        let dir = frames_folder("frames-select", 10);
        let numbers = |frames: &str, stride: usize| -> Vec<usize> {
            let options = DatasetOptions {
                frames: Some(frames.parse::<FrameRange>().unwrap()),
                stride,
                ..DatasetOptions::default()
            };
            let dataset = Dataset::open(dir.path(), &options).unwrap();
            dataset.frames().map(|f| f.unwrap().index).collect()
        };
        assert_eq!(numbers("2..5", 1), [2, 3, 4]);
        assert_eq!(numbers("..10", 3), [0, 3, 6, 9]);
        assert_eq!(numbers("7..", 2), [7, 9]);
        assert_eq!(numbers("3..4", 5), [3]);
        let options = DatasetOptions {
            frames: Some("20..30".parse().unwrap()),
            ..DatasetOptions::default()
        };
        let e = Dataset::open(dir.path(), &options).unwrap_err().to_string();
        assert_eq!(
            e,
            "invalid frames: 20..30 selects none of the 10 frames (numbered 0 to 9)"
        );
    }

    #[test]
    fn missing_pose_is_an_error_naming_the_file() {
        let dir = frames_folder("frames-missing-pose", 3);
        let missing = dir.path().join("frame-000001.pose.txt");
        std::fs::remove_file(&missing).unwrap();
        let dataset = Dataset::open(dir.path(), &DatasetOptions::default()).unwrap();
        assert!(dataset.frame(0).unwrap().pose.is_some());
        let e = dataset.frame(1).unwrap_err();
        assert!(
            matches!(e, Error::Io { ref path, .. } if path == &missing),
            "{e}"
        );

        // A folder without any pose file is fine: no poses at all.
        for n in [0, 2] {
            std::fs::remove_file(dir.path().join(format!("frame-{n:06}.pose.txt"))).unwrap();
        }
        let dataset = Dataset::open(dir.path(), &DatasetOptions::default()).unwrap();
        assert!(dataset.frames().all(|f| f.unwrap().pose.is_none()));
    }

    #[test]
    fn bad_poses_are_errors_naming_the_file() {
        let dir = ScratchDir::new("frames-bad-pose");
        let path = dir.path().join("frame-000000.pose.txt");
        for (body, expected) in [
            ("1 0 0 0\n0 1 0 0\n0 0 1 0\n", "found 12 numbers"),
            ("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 1\n", "bottom row"),
            ("2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", "not orthonormal"),
            ("-1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", "reflection"),
            (
                "1 0 0 0\n0 1 0 0\n0 0 1 -inf\n0 0 0 1\n",
                "line 3: \"-inf\"",
            ),
        ] {
            std::fs::write(&path, body).unwrap();
            let e = read_pose(&path).unwrap_err().to_string();
            assert!(
                e.starts_with(&path.display().to_string()) && e.contains(expected),
                "{e}"
            );
        }
    }

    #[test]
    fn missing_intrinsics_asks_for_the_flag() {
        let dir = frames_folder("frames-no-intrinsics", 2);
        std::fs::remove_file(dir.path().join("camera-intrinsics.txt")).unwrap();
        let e = Dataset::open(dir.path(), &DatasetOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("invalid intrinsics: ")
                && e.contains("has no camera-intrinsics.txt: pass --intrinsics fx,fy,cx,cy"),
            "{e}"
        );
        let options = DatasetOptions {
            intrinsics: Some(IntrinsicsSpec::from_arg("7,7,1.5,1").unwrap()),
            ..DatasetOptions::default()
        };
        let dataset = Dataset::open(dir.path(), &options).unwrap();
        assert_eq!(dataset.intrinsics().fx, 7.0);
        assert_eq!(dataset.intrinsics().width, 4);
    }
}
