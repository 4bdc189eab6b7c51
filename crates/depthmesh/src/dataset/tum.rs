//! TUM RGB-D sequences: `depth.txt` and `rgb.txt` list `timestamp filename`,
//! `groundtruth.txt` holds camera-to-world poses (`timestamp tx ty tz qx qy qz qw`),
//! depth PNGs are 16-bit in units of 1/5000 m. Depth frames are the sequence;
//! colour and pose are associated to each by time.

use super::{choose_intrinsics, DatasetOptions, FrameFiles, FramePose, Index, IntrinsicsSpec};
use crate::camera::Pose;
use crate::error::{Error, Result};
use crate::trajectory::parse_tum;
use std::path::Path;

/// Colour is taken within this many seconds of the depth frame: at 30 Hz a
/// frame is 0.033 s, so a wider window could pick the neighbouring frame.
const COLOR_TOLERANCE: f64 = 0.02;

/// Ground truth (100 Hz or more) is interpolated between entries at most this
/// far from the depth frame; gaps longer than that are motion-capture dropouts.
const POSE_TOLERANCE: f64 = 0.1;

/// The TUM depth images are 640×480 with the factory calibration of each
/// Freiburg sensor, as published with the dataset.
const FREIBURG: [(&str, [f32; 4]); 3] = [
    ("freiburg1", [517.3, 516.5, 318.6, 255.3]),
    ("freiburg2", [520.9, 521.0, 325.1, 249.7]),
    ("freiburg3", [535.4, 539.2, 320.1, 247.6]),
];

/// Lists the depth frames of the TUM sequence in `dir`, with associated colour
/// (when `options.color`) and ground-truth poses (when `groundtruth.txt` exists).
pub(super) fn index(dir: &Path, options: &DatasetOptions) -> Result<Index> {
    let depth_path = dir.join("depth.txt");
    let depth_text = std::fs::read_to_string(&depth_path).map_err(|e| Error::io(&depth_path, e))?;
    let depth = parse_list(&depth_text, &depth_path)?;
    if depth.is_empty() {
        return Err(Error::format(&depth_path, "lists no depth images"));
    }
    // rgb.txt is only parsed when colour is wanted, so a broken one cannot stop a depth-only run.
    let mut rgb = Vec::new();
    if options.color {
        let path = dir.join("rgb.txt");
        if let Some(text) = read_optional(&path)? {
            rgb = parse_list(&text, &path)?;
        }
    }
    rgb.sort_by(|a, b| a.0.total_cmp(&b.0));
    let ground_truth_path = dir.join("groundtruth.txt");
    let mut ground_truth = match read_optional(&ground_truth_path)? {
        Some(text) => parse_tum(&text, &ground_truth_path)?,
        None => Vec::new(),
    };
    ground_truth.sort_by(|a, b| a.0.total_cmp(&b.0));

    let frames = depth
        .into_iter()
        .enumerate()
        .map(|(number, (timestamp, file))| FrameFiles {
            number,
            timestamp,
            depth: dir.join(file),
            color: nearest(&rgb, timestamp)
                .filter(|(t, _)| (t - timestamp).abs() <= COLOR_TOLERANCE)
                .map(|(_, file)| dir.join(file)),
            pose: pose_at(&ground_truth, timestamp).map_or(FramePose::Absent, FramePose::Known),
        })
        .collect();

    let intrinsics = choose_intrinsics(
        options,
        &dir.join("intrinsics.txt"),
        freiburg_intrinsics(dir),
        || {
            format!(
                "{} has no intrinsics.txt and its name does not say freiburg1, 2 or 3",
                dir.display()
            )
        },
    )?;
    Ok(Index {
        depth_units_per_metre: 5000.0,
        intrinsics,
        frames,
    })
}

/// A file's text, or `None` when it does not exist (TUM test sequences have no ground truth).
fn read_optional(path: &Path) -> Result<Option<String>> {
    match std::fs::read_to_string(path) {
        Ok(text) => Ok(Some(text)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(Error::io(path, e)),
    }
}

/// Parses `timestamp filename` lines, skipping blank lines and `#` comments.
fn parse_list(text: &str, source: &Path) -> Result<Vec<(f64, String)>> {
    let mut entries = Vec::new();
    for (number, line) in crate::trajectory::data_lines(text) {
        let fail = |message: String| Error::format(source, format!("line {number}: {message}"));
        let fields: Vec<&str> = line.split_whitespace().collect();
        let [timestamp, file] = fields[..] else {
            return Err(fail(format!(
                "expected \"timestamp filename\", found {} fields",
                fields.len()
            )));
        };
        let timestamp = timestamp
            .parse::<f64>()
            .ok()
            .filter(|t| t.is_finite())
            .ok_or_else(|| fail(format!("\"{timestamp}\" is not a timestamp")))?;
        entries.push((timestamp, file.to_owned()));
    }
    Ok(entries)
}

/// The entry of time-sorted `list` nearest to `t`.
fn nearest<T>(list: &[(f64, T)], t: f64) -> Option<&(f64, T)> {
    let after = list.partition_point(|(s, _)| *s < t);
    let before = after.checked_sub(1).and_then(|i| list.get(i));
    match (before, list.get(after)) {
        (Some(b), Some(a)) => Some(if t - b.0 <= a.0 - t { b } else { a }),
        (b, a) => b.or(a),
    }
}

/// The pose at time `t`, interpolated between the bracketing ground-truth
/// entries (linear translation, slerp rotation) when both are within
/// [`POSE_TOLERANCE`]; `None` outside the ground truth or across a gap.
fn pose_at(ground_truth: &[(f64, Pose)], t: f64) -> Option<Pose> {
    let after = ground_truth.partition_point(|(s, _)| *s < t);
    let (t1, p1) = ground_truth.get(after)?;
    if *t1 == t {
        return Some(*p1);
    }
    let (t0, p0) = ground_truth.get(after.checked_sub(1)?)?;
    if t - t0 > POSE_TOLERANCE || t1 - t > POSE_TOLERANCE {
        return None;
    }
    let a = ((t - t0) / (t1 - t0)) as f32;
    Some(Pose::from_quat(
        p0.quat().slerp(p1.quat(), a),
        p0.translation.lerp(p1.translation, a),
    ))
}

/// The published intrinsics of a Freiburg sensor, recognised by the folder's
/// name (`rgbd_dataset_freiburg1_desk` and the like).
fn freiburg_intrinsics(dir: &Path) -> Option<IntrinsicsSpec> {
    // Canonical, so "." and "seq/" are named too.
    let full = dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf());
    let name = full.file_name()?.to_str()?;
    let (_, [fx, fy, cx, cy]) = FREIBURG.iter().find(|(key, _)| name.contains(key))?;
    Some(IntrinsicsSpec {
        fx: *fx,
        fy: *fy,
        cx: *cx,
        cy: *cy,
        size: Some((640, 480)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::scratch::ScratchDir;
    use crate::dataset::test_util::{write_png, write_rgb_png};
    use crate::dataset::{Dataset, Layout};
    use glam::{Quat, Vec3};
    use std::path::PathBuf;

    /// Depth frames at these times (s), 33 ms apart like a 30 Hz sensor.
    const DEPTH_TIMES: [f64; 4] = [100.0, 100.033, 100.066, 100.3];

    /// A `freiburg1` TUM folder inside a scratch directory: four 640×480 depth
    /// frames of 1.5 m (7500 units), colour 10 ms after the first three and
    /// 50 ms after the last, ground truth at 99.95 (origin), 100.05 (1 m along
    /// x, 90° about z) and 100.3.
    fn tum_folder(tag: &str) -> (ScratchDir, PathBuf) {
        let scratch = ScratchDir::new(tag);
        let dir = scratch.path().join("rgbd_dataset_freiburg1_synthetic");
        std::fs::create_dir_all(dir.join("depth")).unwrap();
        std::fs::create_dir_all(dir.join("rgb")).unwrap();
        let mut depth_txt = String::from("# depth maps\n# file: synthetic\n# timestamp filename\n");
        let mut rgb_txt = String::from("# colour images\n");
        for (i, &t) in DEPTH_TIMES.iter().enumerate() {
            let depth = format!("depth/{t:.6}.png");
            write_png(&dir.join(&depth), 640, 480, &vec![7500; 640 * 480]);
            depth_txt += &format!("{t:.6} {depth}\n");
            let tc = t + if i < 3 { 0.01 } else { 0.05 };
            let rgb = format!("rgb/{tc:.6}.png");
            write_rgb_png(&dir.join(&rgb), 2, 2, &[[i as u8, 0, 0]; 4]);
            rgb_txt += &format!("{tc:.6} {rgb}\n");
        }
        std::fs::write(dir.join("depth.txt"), depth_txt).unwrap();
        std::fs::write(dir.join("rgb.txt"), rgb_txt).unwrap();
        let q = Quat::from_rotation_z(std::f32::consts::FRAC_PI_2);
        std::fs::write(
            dir.join("groundtruth.txt"),
            format!(
                "# ground truth\n99.95 0 0 0 0 0 0 1\n100.05 1 0 0 {} {} {} {}\n100.3 2 2 2 0 0 0 1\n",
                q.x, q.y, q.z, q.w
            ),
        )
        .unwrap();
        (scratch, dir)
    }

    #[test]
    fn reads_and_associates() {
        let (_scratch, dir) = tum_folder("tum");
        let options = DatasetOptions {
            color: true,
            ..DatasetOptions::default()
        };
        let dataset = Dataset::open(&dir, &options).unwrap();
        assert_eq!(dataset.layout(), Layout::Tum);
        assert_eq!(dataset.len(), 4);
        let k = dataset.intrinsics();
        assert_eq!(
            (k.width, k.height, k.fx, k.fy, k.cx, k.cy),
            (640, 480, 517.3, 516.5, 318.6, 255.3)
        );

        let frames: Vec<_> = dataset.frames().map(|f| f.unwrap()).collect();
        for (i, frame) in frames.iter().enumerate() {
            assert_eq!((frame.index, frame.timestamp), (i, DEPTH_TIMES[i]));
            assert_eq!(frame.depth.data[1234], 1.5);
        }
        // Colour 10 ms away is taken, 50 ms away is not.
        assert_eq!(frames[2].color.as_ref().unwrap().data[0], [2, 0, 0]);
        assert!(frames[3].color.is_none());

        // Halfway between the first two ground-truth entries: half the
        // translation and half the rotation.
        let pose = frames[0].pose.unwrap();
        assert!(pose.translation.abs_diff_eq(Vec3::new(0.5, 0.0, 0.0), 1e-5));
        let half = Quat::from_rotation_z(std::f32::consts::FRAC_PI_4);
        assert!(pose.quat().abs_diff_eq(half, 1e-5), "{:?}", pose.quat());
        let a = (0.033 + 0.05) / 0.1;
        assert!(frames[1]
            .pose
            .unwrap()
            .translation
            .abs_diff_eq(Vec3::new(a, 0.0, 0.0), 1e-4));
        // 100.066 lies between entries 0.25 s apart: no pose. 100.3 is an entry.
        assert!(frames[2].pose.is_none());
        assert_eq!(frames[3].pose.unwrap().translation, Vec3::splat(2.0));

        // Selection uses 0-based line numbers of depth.txt.
        let options = DatasetOptions {
            frames: Some("1..".parse().unwrap()),
            stride: 2,
            ..DatasetOptions::default()
        };
        let dataset = Dataset::open(&dir, &options).unwrap();
        let picked: Vec<_> = dataset.frames().map(|f| f.unwrap().index).collect();
        assert_eq!(picked, [1, 3]);
        assert!(dataset.frame(0).unwrap().color.is_none());
    }

    #[test]
    fn intrinsics_sources() {
        let (scratch, fr1) = tum_folder("tum-intrinsics");
        // Without ground truth, poses are absent.
        std::fs::remove_file(fr1.join("groundtruth.txt")).unwrap();
        let other = scratch.path().join("my_sequence");
        std::fs::rename(&fr1, &other).unwrap();
        let e = Dataset::open(&other, &DatasetOptions::default())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("has no intrinsics.txt and its name does not say freiburg1, 2 or 3: pass --intrinsics"),
            "{e}"
        );
        std::fs::write(other.join("intrinsics.txt"), "640 480 500 501 320 240\n").unwrap();
        let dataset = Dataset::open(&other, &DatasetOptions::default()).unwrap();
        assert_eq!(dataset.intrinsics().fy, 501.0);
        assert!(dataset.frame(0).unwrap().pose.is_none());
        // The flag wins over the file; a size that disagrees with the images names the image.
        let options = DatasetOptions {
            intrinsics: Some(IntrinsicsSpec::from_arg("400,400,160,120,320,240").unwrap()),
            ..DatasetOptions::default()
        };
        let dataset = Dataset::open(&other, &options).unwrap();
        assert_eq!(dataset.intrinsics().fx, 400.0);
        let e = dataset.frame(0).unwrap_err().to_string();
        assert!(
            e.contains("100.000000.png: depth image is 640×480 but the camera is 320×240"),
            "{e}"
        );

        let fr3 = scratch
            .path()
            .join("rgbd_dataset_freiburg3_long_office_household");
        std::fs::rename(&other, &fr3).unwrap();
        std::fs::remove_file(fr3.join("intrinsics.txt")).unwrap();
        // The name is found when the path ends in "." too.
        let dataset = Dataset::open(&fr3.join("."), &DatasetOptions::default()).unwrap();
        assert_eq!(dataset.intrinsics().fy, 539.2);
    }

    #[test]
    fn lists_and_nearest() {
        let source = Path::new("depth.txt");
        let e = parse_list("1.0 a.png\n2.0\n", source)
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "depth.txt: line 2: expected \"timestamp filename\", found 1 fields"
        );
        let e = parse_list("x a.png\n", source).unwrap_err().to_string();
        assert_eq!(e, "depth.txt: line 1: \"x\" is not a timestamp");
        let list = [(1.0, 'a'), (2.0, 'b'), (4.0, 'c')];
        let pick = |t| nearest(&list, t).map(|e| e.1);
        assert_eq!(
            [pick(0.0), pick(1.4), pick(1.6), pick(3.5), pick(9.0)],
            [Some('a'), Some('a'), Some('b'), Some('c'), Some('c')]
        );
        assert_eq!(nearest::<char>(&[], 1.0), None);
    }
}
