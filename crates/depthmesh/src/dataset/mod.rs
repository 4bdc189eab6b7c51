//! Dataset readers: 7-Scenes "frames folders" and TUM RGB-D sequences, told
//! apart by their files, giving [`Frame`]s with depth in metres and
//! camera-to-world poses.
//!
//! Opening a dataset resolves every selected frame's files (and, for TUM, its
//! associated colour image and interpolated pose), so reading a frame is only
//! decoding and one frame's bad file never stops the others from being read.

mod color;
mod depth_png;
mod frames_folder;
mod frames_writer;
mod intrinsics;
#[cfg(test)]
mod test_util;
mod tum;

pub use depth_png::{read_depth_png, read_depth_png_raw};
pub use frames_writer::FramesWriter;
pub use intrinsics::IntrinsicsSpec;

use crate::camera::{Intrinsics, Pose};
use crate::codec::RawDepth;
use crate::error::{Error, Result};
use crate::image::{DepthImage, Frame};
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// Which frames of a dataset to read, and how.
#[derive(Clone, Debug, PartialEq)]
pub struct DatasetOptions {
    /// Frame numbers to read (`--frames`); all when `None`.
    pub frames: Option<FrameRange>,
    /// Read every `stride`-th frame of the range, starting with its first (`--stride`).
    pub stride: usize,
    /// Depths nearer than this, in metres, become "no measurement" (`--depth-min`).
    pub depth_min: f32,
    /// Depths farther than this, in metres, become "no measurement" (`--depth-max`).
    pub depth_max: f32,
    /// Intrinsics overriding the dataset's own (`--intrinsics`).
    pub intrinsics: Option<IntrinsicsSpec>,
    /// Read colour images too, where the dataset has them.
    pub color: bool,
    /// Leave out unreadable frames instead of failing (`--skip-bad-frames`); see [`Frames`].
    pub skip_bad_frames: bool,
    /// Depth PNG units per metre overriding the layout's own (1000, millimetres,
    /// for 7-Scenes; 5000 for TUM) (`--depth-scale`).
    pub depth_units_per_metre: Option<f32>,
}

impl Default for DatasetOptions {
    /// Every frame, depth limited to 0.1–4.0 m (the working range of
    /// Kinect-class sensors), no colour.
    fn default() -> Self {
        DatasetOptions {
            frames: None,
            stride: 1,
            depth_min: 0.1,
            depth_max: 4.0,
            intrinsics: None,
            color: false,
            skip_bad_frames: false,
            depth_units_per_metre: None,
        }
    }
}

impl DatasetOptions {
    fn validate(&self) -> Result<()> {
        if let Some(units) = self.depth_units_per_metre {
            if !(units.is_finite() && units > 0.0) {
                return Err(Error::parameter(
                    "depth_scale",
                    format!("{units} units per metre must be positive (1000 for millimetres)"),
                ));
            }
        }
        if self.stride == 0 {
            return Err(Error::parameter("stride", "must be at least 1"));
        }
        if !(self.depth_min.is_finite() && self.depth_min >= 0.0) {
            return Err(Error::parameter(
                "depth_min",
                format!("{} m must be zero or more", self.depth_min),
            ));
        }
        if !(self.depth_max.is_finite() && self.depth_max > self.depth_min) {
            return Err(Error::parameter(
                "depth_max",
                format!(
                    "{} m must be more than depth_min ({} m)",
                    self.depth_max, self.depth_min
                ),
            ));
        }
        Ok(())
    }
}

/// A half-open range of frame numbers, like a Rust range: `A..B`, `A..` or `..B`.
/// Numbers are those in 7-Scenes file names, or 0-based lines of TUM's `depth.txt`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameRange {
    /// First frame number included.
    pub start: usize,
    /// First frame number excluded; `None` runs to the end.
    pub end: Option<usize>,
}

impl FrameRange {
    /// Whether frame number `n` is in the range.
    pub fn contains(&self, n: usize) -> bool {
        n >= self.start && self.end.is_none_or(|end| n < end)
    }
}

impl FromStr for FrameRange {
    type Err = Error;

    /// Parses `A..B`, `A..` or `..B`; errors name `--frames`.
    fn from_str(s: &str) -> Result<Self> {
        let fail = |message: String| Error::parameter("frames", message);
        let (a, b) = s.split_once("..").ok_or_else(|| {
            fail(format!(
                "\"{s}\" is not a range of frame numbers A..B, A.. or ..B"
            ))
        })?;
        if b.starts_with('=') {
            return Err(fail(format!(
                "\"{s}\": ranges are half-open like Rust's A..B; write the end as one past the last frame"
            )));
        }
        let number = |text: &str| -> Result<Option<usize>> {
            let text = text.trim();
            if text.is_empty() {
                return Ok(None);
            }
            text.parse()
                .map(Some)
                .map_err(|_| fail(format!("\"{text}\" in \"{s}\" is not a frame number")))
        };
        let range = FrameRange {
            start: number(a)?.unwrap_or(0),
            end: number(b)?,
        };
        match range.end {
            Some(end) if end <= range.start => Err(fail(format!(
                "\"{s}\" is empty: the range is half-open, so the end must be past the start"
            ))),
            _ => Ok(range),
        }
    }
}

impl fmt::Display for FrameRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.end {
            Some(end) => write!(f, "{}..{end}", self.start),
            None => write!(f, "{}..", self.start),
        }
    }
}

/// The on-disk layouts the readers understand.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// 7-Scenes: `frame-NNNNNN.depth.png` (millimetres) with `.color.jpg` or
    /// `.color.png`, `.pose.txt` (4×4 camera-to-world) and `camera-intrinsics.txt`.
    FramesFolder,
    /// TUM RGB-D: `depth.txt`, `rgb.txt` and `groundtruth.txt`, depth in units of 1/5000 m.
    Tum,
}

/// Where a frame's pose comes from.
#[derive(Clone, Debug)]
enum FramePose {
    /// The dataset has no poses.
    Absent,
    /// Known when the dataset was opened (TUM, associated from `groundtruth.txt`).
    Known(Pose),
    /// A 7-Scenes pose file, read with the frame so a bad one is that frame's error.
    File(PathBuf),
}

impl FramePose {
    /// The pose, reading its file if it has one.
    fn read(&self) -> Result<Option<Pose>> {
        Ok(match self {
            FramePose::Absent => None,
            FramePose::Known(pose) => Some(*pose),
            FramePose::File(path) => Some(frames_folder::read_pose(path)?),
        })
    }
}

/// One frame's files and metadata, as a reader finds them.
#[derive(Clone, Debug)]
struct FrameFiles {
    number: usize,
    timestamp: f64,
    depth: PathBuf,
    color: Option<PathBuf>,
    pose: FramePose,
}

/// What a layout's reader finds in a folder: every frame, in order, before selection.
struct Index {
    depth_units_per_metre: f32,
    intrinsics: IntrinsicsSpec,
    frames: Vec<FrameFiles>,
}

/// What identifies a frame besides its images.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameInfo {
    /// The frame's number, as in its file names.
    pub index: usize,
    /// Its timestamp in seconds (the dataset's own, or the frame number).
    pub timestamp: f64,
    /// Its camera-to-world pose, when the dataset has one.
    pub pose: Option<Pose>,
}

/// An opened dataset: a sequence of selected frames read on demand.
#[derive(Debug)]
pub struct Dataset {
    layout: Layout,
    intrinsics: Intrinsics,
    depth_units_per_metre: f32,
    frames: Vec<FrameFiles>,
    options: DatasetOptions,
}

impl Dataset {
    /// Opens the dataset in folder `path`, detecting its layout, and selects
    /// frames as `options` say. Errors name the file or the option at fault.
    pub fn open(path: &Path, options: &DatasetOptions) -> Result<Dataset> {
        options.validate()?;
        let metadata = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
        if !metadata.is_dir() {
            return Err(Error::format(
                path,
                "is not a folder (expected a 7-Scenes frames folder or a TUM RGB-D folder)",
            ));
        }
        let (layout, index) = if path.join("depth.txt").is_file() {
            (Layout::Tum, tum::index(path, options)?)
        } else if let Some(index) = frames_folder::index(path, options)? {
            (Layout::FramesFolder, index)
        } else {
            return Err(Error::format(
                path,
                "is neither a 7-Scenes frames folder (frame-NNNNNN.depth.png) nor a TUM RGB-D folder (depth.txt)",
            ));
        };
        let frames = select(index.frames, options)?;
        let (width, height) = match index.intrinsics.size {
            Some(size) => size,
            None => first_image_size(&frames, options.skip_bad_frames)?,
        };
        let intrinsics = index.intrinsics.resolve(width, height);
        intrinsics.validate()?;
        Ok(Dataset {
            layout,
            intrinsics,
            depth_units_per_metre: options
                .depth_units_per_metre
                .unwrap_or(index.depth_units_per_metre),
            frames,
            options: options.clone(),
        })
    }

    /// The layout that was detected.
    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// The depth camera's intrinsics; every depth image has its size.
    pub fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    /// Number of frames selected by the range and stride.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether no frame is selected (never, for a dataset that opened).
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Reads the `i`-th selected frame: depth in metres with values outside
    /// `[depth_min, depth_max]` set to 0, colour when asked for and present, the pose when known.
    pub fn frame(&self, i: usize) -> Result<Frame> {
        let files = self.files(i)?;
        let mut raw = RawDepth::default();
        self.raw_depth(i, &mut raw)?;
        let mut depth = DepthImage::default();
        raw.to_metres(&mut depth);
        depth.clamp_range(self.options.depth_min, self.options.depth_max);
        let color = match &files.color {
            Some(path) if self.options.color => Some(color::read_color(path)?),
            _ => None,
        };
        let pose = files.pose.read()?;
        Ok(Frame {
            index: files.number,
            timestamp: files.timestamp,
            depth,
            color,
            pose,
        })
    }

    /// Reads the `i`-th selected frame's depth into `out` as stored, in the
    /// sensor's units, without the depth range applied: what a client sends
    /// losslessly. [`RawDepth::to_metres`] then
    /// [`DepthImage::clamp_range`]`(depth_min, depth_max)` give exactly the
    /// depth of [`Dataset::frame`].
    pub fn raw_depth(&self, i: usize, out: &mut RawDepth) -> Result<()> {
        let files = self.files(i)?;
        read_depth_png_raw(&files.depth, self.depth_units_per_metre, out)?;
        let k = &self.intrinsics;
        if (out.width(), out.height()) != (k.width, k.height) {
            return Err(Error::format(
                &files.depth,
                format!(
                    "depth image is {}×{} but the camera is {}×{} (check the intrinsics)",
                    out.width(),
                    out.height(),
                    k.width,
                    k.height
                ),
            ));
        }
        Ok(())
    }

    /// The `i`-th selected frame's number, timestamp and pose, without
    /// reading its images (a client pairs them with [`Dataset::raw_depth`]).
    pub fn frame_info(&self, i: usize) -> Result<FrameInfo> {
        let files = self.files(i)?;
        Ok(FrameInfo {
            index: files.number,
            timestamp: files.timestamp,
            pose: files.pose.read()?,
        })
    }

    fn files(&self, i: usize) -> Result<&FrameFiles> {
        self.frames.get(i).ok_or_else(|| {
            Error::parameter(
                "frame",
                format!("{i} is past the {} selected frames", self.frames.len()),
            )
        })
    }

    /// The poses of the selected frames that have one, with their
    /// timestamps, without reading any image.
    pub fn trajectory(&self) -> Result<Vec<(f64, Pose)>> {
        let mut poses = Vec::with_capacity(self.frames.len());
        for files in &self.frames {
            if let Some(pose) = files.pose.read()? {
                poses.push((files.timestamp, pose));
            }
        }
        Ok(poses)
    }

    /// The selected frames in order, leaving out bad ones when `skip_bad_frames` is set.
    pub fn frames(&self) -> Frames<'_> {
        self.frames_from(0)
    }

    /// Like [`Dataset::frames`], from the `position`-th selected frame on
    /// (to continue a run that read the ones before).
    pub fn frames_from(&self, position: usize) -> Frames<'_> {
        Frames {
            dataset: self,
            next: position,
            failed: false,
            skipped: Vec::new(),
        }
    }
}

/// A frame left out under `skip_bad_frames`, kept so the caller can report it.
#[derive(Debug)]
pub struct Skipped {
    /// The frame's number (as in file names, or the line in TUM's `depth.txt`).
    pub index: usize,
    /// Why it could not be read; names the file.
    pub error: Error,
}

/// Iterator over a dataset's selected frames. Without `skip_bad_frames` the
/// first bad frame is yielded as an error and iteration stops; with it, bad
/// frames are left out and collected in [`Frames::skipped`], which the caller
/// can check after each frame to report them as they happen.
#[derive(Debug)]
pub struct Frames<'a> {
    dataset: &'a Dataset,
    next: usize,
    failed: bool,
    skipped: Vec<Skipped>,
}

impl Frames<'_> {
    /// How many selected frames were read (or left out) so far, counting
    /// from the start of the selection.
    pub fn position(&self) -> usize {
        self.next
    }

    /// The frames left out so far, in order.
    pub fn skipped(&self) -> &[Skipped] {
        &self.skipped
    }
}

impl Iterator for Frames<'_> {
    type Item = Result<Frame>;

    fn next(&mut self) -> Option<Result<Frame>> {
        while !self.failed && self.next < self.dataset.len() {
            let i = self.next;
            self.next += 1;
            match self.dataset.frame(i) {
                Ok(frame) => return Some(Ok(frame)),
                Err(error) if self.dataset.options.skip_bad_frames => {
                    let index = self.dataset.frames[i].number;
                    self.skipped.push(Skipped { index, error });
                }
                Err(error) => {
                    self.failed = true;
                    return Some(Err(error));
                }
            }
        }
        None
    }
}

/// Keeps the frames in `options.frames`, then every `stride`-th of those.
fn select(frames: Vec<FrameFiles>, options: &DatasetOptions) -> Result<Vec<FrameFiles>> {
    let range = options.frames.unwrap_or_default();
    let total = frames.len();
    let first = frames.first().map_or(0, |f| f.number);
    let last = frames.last().map_or(0, |f| f.number);
    let selected: Vec<FrameFiles> = frames
        .into_iter()
        .filter(|f| range.contains(f.number))
        .step_by(options.stride)
        .collect();
    if selected.is_empty() {
        return Err(Error::parameter(
            "frames",
            format!("{range} selects none of the {total} frames (numbered {first} to {last})"),
        ));
    }
    Ok(selected)
}

/// The image size, from the first depth PNG whose header reads; when bad frames
/// are skipped, a bad first frame must not stop the dataset from opening.
fn first_image_size(frames: &[FrameFiles], skip_bad_frames: bool) -> Result<(u32, u32)> {
    let mut first_error = None;
    for files in frames {
        match depth_png::depth_png_size(&files.depth) {
            Ok(size) => return Ok(size),
            Err(error) if skip_bad_frames => {
                first_error.get_or_insert(error);
            }
            Err(error) => return Err(error),
        }
    }
    Err(first_error.unwrap_or_else(|| {
        Error::parameter("frames", "selects no frame to take the image size from")
    }))
}

/// Explicit intrinsics win over the dataset's file, which wins over a default
/// known from the dataset's name: a user can always correct a dataset.
/// `missing` says what the folder lacks when none of them is there.
fn choose_intrinsics(
    options: &DatasetOptions,
    file: &Path,
    default: Option<IntrinsicsSpec>,
    missing: impl FnOnce() -> String,
) -> Result<IntrinsicsSpec> {
    if let Some(spec) = options.intrinsics {
        return Ok(spec);
    }
    if file.exists() {
        return IntrinsicsSpec::read_file(file);
    }
    default.ok_or_else(|| {
        Error::parameter(
            "intrinsics",
            format!(
                "{}: pass --intrinsics fx,fy,cx,cy[,width,height] or the name of a file holding them",
                missing()
            ),
        )
    })
}

/// The numbers in a small text file (whitespace-separated, `#` starts a comment),
/// as the pose and intrinsics files of both layouts hold.
fn parse_numbers(text: &str) -> std::result::Result<Vec<f64>, String> {
    let mut numbers = Vec::new();
    for (line_index, line) in text.lines().enumerate() {
        let content = line.split('#').next().unwrap_or_default();
        for field in content.split_whitespace() {
            let value = field
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    format!(
                        "line {}: \"{field}\" is not a finite number",
                        line_index + 1
                    )
                })?;
            numbers.push(value);
        }
    }
    Ok(numbers)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::scratch::ScratchDir;
    use crate::dataset::test_util::frames_folder;

    #[test]
    fn frame_ranges() {
        let parse = |s: &str| s.parse::<FrameRange>();
        assert_eq!(
            parse("10..300").unwrap(),
            FrameRange {
                start: 10,
                end: Some(300)
            }
        );
        assert_eq!(
            parse("..100").unwrap(),
            FrameRange {
                start: 0,
                end: Some(100)
            }
        );
        assert_eq!(
            parse("5..").unwrap(),
            FrameRange {
                start: 5,
                end: None
            }
        );
        assert_eq!(parse(" 1 .. 2 ").unwrap().to_string(), "1..2");
        assert_eq!(parse("5..").unwrap().to_string(), "5..");
        let range = parse("2..4").unwrap();
        assert!(!range.contains(1) && range.contains(2) && range.contains(3) && !range.contains(4));
        for (s, expected) in [
            ("10", "is not a range"),
            ("a..3", "\"a\" in \"a..3\" is not a frame number"),
            ("1..-3", "\"-3\""),
            ("5..5", "is empty"),
            ("9..3", "is empty"),
            ("1..=3", "half-open"),
        ] {
            let e = parse(s).unwrap_err().to_string();
            assert!(
                e.starts_with("invalid frames: ") && e.contains(expected),
                "{e}"
            );
        }
    }

    #[test]
    fn rejects_bad_options() {
        let dir = frames_folder("dataset-options", 1);
        for (options, flag) in [
            (
                DatasetOptions {
                    stride: 0,
                    ..DatasetOptions::default()
                },
                "stride",
            ),
            (
                DatasetOptions {
                    depth_min: -1.0,
                    ..DatasetOptions::default()
                },
                "depth_min",
            ),
            (
                DatasetOptions {
                    depth_max: 0.05,
                    ..DatasetOptions::default()
                },
                "depth_max",
            ),
            (
                DatasetOptions {
                    depth_max: f32::NAN,
                    ..DatasetOptions::default()
                },
                "depth_max",
            ),
        ] {
            let e = Dataset::open(dir.path(), &options).unwrap_err().to_string();
            assert!(e.starts_with(&format!("invalid {flag}: ")), "{e}");
        }
    }

    #[test]
    fn detects_neither_layout() {
        let dir = ScratchDir::new("dataset-neither");
        std::fs::write(dir.path().join("frame-1.color.jpg"), b"").unwrap();
        std::fs::write(dir.path().join("frame-x.depth.png"), b"").unwrap();
        let e = Dataset::open(dir.path(), &DatasetOptions::default())
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            format!(
                "{}: is neither a 7-Scenes frames folder (frame-NNNNNN.depth.png) nor a TUM RGB-D folder (depth.txt)",
                dir.path().display()
            )
        );
        let file = dir.path().join("frame-1.color.jpg");
        let e = Dataset::open(&file, &DatasetOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("is not a folder"), "{e}");
        let missing = dir.path().join("nowhere");
        let e = Dataset::open(&missing, &DatasetOptions::default()).unwrap_err();
        assert!(matches!(e, Error::Io { ref path, .. } if path == &missing));
    }

    #[test]
    fn raw_depth_is_the_stored_values_and_converts_to_the_frames_depth() {
        let dir = frames_folder("dataset-raw", 2);
        let options = DatasetOptions {
            depth_max: 1.05,
            ..DatasetOptions::default()
        };
        let dataset = Dataset::open(dir.path(), &options).unwrap();
        let mut raw = RawDepth::default();
        for i in 0..2 {
            dataset.raw_depth(i, &mut raw).unwrap();
            let stored = 1000 + 100 * i as u16;
            assert_eq!(raw.data()[..3], [0, 65535, stored]);
            assert_eq!(raw.units_per_metre(), 1000.0);
            let mut depth = DepthImage::default();
            raw.to_metres(&mut depth);
            depth.clamp_range(options.depth_min, options.depth_max);
            assert_eq!(depth, dataset.frame(i).unwrap().depth);
        }
        assert!(dataset.raw_depth(2, &mut raw).is_err());
    }

    #[test]
    fn corrupt_frame_fails_or_is_skipped() {
        let dir = frames_folder("dataset-corrupt", 4);
        let corrupt = dir.path().join("frame-000002.depth.png");
        std::fs::write(&corrupt, b"\x89PNG\r\n\x1a\n garbage").unwrap();

        let dataset = Dataset::open(dir.path(), &DatasetOptions::default()).unwrap();
        let mut frames = dataset.frames();
        assert_eq!(frames.next().unwrap().unwrap().index, 0);
        assert_eq!(frames.next().unwrap().unwrap().index, 1);
        let e = frames.next().unwrap().unwrap_err().to_string();
        assert!(e.starts_with(&corrupt.display().to_string()), "{e}");
        assert!(
            frames.next().is_none(),
            "iteration stops at the first bad frame"
        );

        let options = DatasetOptions {
            skip_bad_frames: true,
            ..DatasetOptions::default()
        };
        let dataset = Dataset::open(dir.path(), &options).unwrap();
        let mut frames = dataset.frames();
        let read: Vec<usize> = frames.by_ref().map(|f| f.unwrap().index).collect();
        assert_eq!(read, [0, 1, 3]);
        let [skipped] = frames.skipped() else {
            panic!("expected one skipped frame, got {:?}", frames.skipped());
        };
        assert_eq!(skipped.index, 2);
        assert!(skipped.error.to_string().contains("frame-000002.depth.png"));

        // A bad first frame does not stop the size being found when skipping.
        std::fs::write(dir.path().join("frame-000000.depth.png"), b"").unwrap();
        assert!(Dataset::open(dir.path(), &DatasetOptions::default()).is_err());
        let dataset = Dataset::open(dir.path(), &options).unwrap();
        assert_eq!(dataset.intrinsics().width, 4);
        assert_eq!(dataset.frames().count(), 2);
    }
}
