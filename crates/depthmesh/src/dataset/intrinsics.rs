//! Camera intrinsics given by the user (`--intrinsics`) or by a small file in a dataset.

use super::parse_numbers;
use crate::camera::Intrinsics;
use crate::error::{Error, Result};
use std::path::Path;

/// The flag the command line uses for intrinsics, named in errors.
const FLAG: &str = "--intrinsics";

/// Pinhole parameters as a user or a dataset gives them. The image size is
/// often left out (7-Scenes' `camera-intrinsics.txt` has none); it then comes
/// from the depth images.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IntrinsicsSpec {
    /// Focal length along x, in pixels.
    pub fx: f32,
    /// Focal length along y, in pixels.
    pub fy: f32,
    /// Principal point x, in pixels.
    pub cx: f32,
    /// Principal point y, in pixels.
    pub cy: f32,
    /// Image width and height, when given.
    pub size: Option<(u32, u32)>,
}

impl IntrinsicsSpec {
    /// Checks the numbers; the message is wrapped by the caller, who knows whether
    /// they came from the flag or from a file.
    fn new(values: [f64; 4], size: Option<[f64; 2]>) -> std::result::Result<Self, String> {
        let [fx, fy, cx, cy] = values;
        if !(fx > 0.0 && fy > 0.0) {
            return Err(format!(
                "focal lengths must be positive (fx = {fx}, fy = {fy})"
            ));
        }
        let size = match size {
            None => None,
            Some([w, h]) => {
                let pixels = |v: f64| {
                    (v >= 1.0 && v <= f64::from(u32::MAX) && v.fract() == 0.0).then_some(v as u32)
                };
                match (pixels(w), pixels(h)) {
                    (Some(w), Some(h)) => Some((w, h)),
                    _ => {
                        return Err(format!(
                            "image size {w}×{h} is not two positive whole numbers"
                        ))
                    }
                }
            }
        };
        Ok(IntrinsicsSpec {
            fx: fx as f32,
            fy: fy as f32,
            cx: cx as f32,
            cy: cy as f32,
            size,
        })
    }

    /// Parses the value of `--intrinsics`: either `fx,fy,cx,cy[,width,height]`
    /// or, when it holds no comma, the name of a file read by [`IntrinsicsSpec::read_file`].
    pub fn from_arg(arg: &str) -> Result<Self> {
        if !arg.contains(',') {
            return Self::read_file(Path::new(arg));
        }
        let values = arg
            .split(',')
            .map(|field| {
                let field = field.trim();
                field
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| {
                        Error::parameter(FLAG, format!("\"{field}\" is not a finite number"))
                    })
            })
            .collect::<Result<Vec<f64>>>()?;
        let spec = match values[..] {
            [fx, fy, cx, cy] => Self::new([fx, fy, cx, cy], None),
            [fx, fy, cx, cy, w, h] => Self::new([fx, fy, cx, cy], Some([w, h])),
            _ => Err(format!(
                "expected fx,fy,cx,cy or fx,fy,cx,cy,width,height, found {} numbers in \"{arg}\"",
                values.len()
            )),
        };
        spec.map_err(|message| Error::parameter(FLAG, message))
    }

    /// Reads intrinsics from a file holding either a 3×3 camera matrix K (the
    /// 7-Scenes `camera-intrinsics.txt`) or one line `width height fx fy cx cy`;
    /// `#` starts a comment.
    pub fn read_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let v = parse_numbers(&text).map_err(|message| Error::format(path, message))?;
        let spec = match v[..] {
            [fx, skew, cx, k10, fy, cy, k20, k21, k22] => {
                // A pinhole model has no skew; the last row of K is fixed by definition.
                let zeros = [skew, k10, k20, k21];
                if zeros.iter().all(|v| v.abs() <= 1e-9) && (k22 - 1.0).abs() <= 1e-9 {
                    Self::new([fx, fy, cx, cy], None)
                } else {
                    Err("K must be [fx 0 cx; 0 fy cy; 0 0 1]".to_owned())
                }
            }
            [w, h, fx, fy, cx, cy] => Self::new([fx, fy, cx, cy], Some([w, h])),
            _ => Err(format!(
                "expected a 3×3 camera matrix (9 numbers) or \"width height fx fy cx cy\" (6 numbers), found {} numbers",
                v.len()
            )),
        };
        spec.map_err(|message| Error::format(path, message))
    }

    /// The full model: the size given here, else `width × height` (that of the depth images).
    pub fn resolve(&self, width: u32, height: u32) -> Intrinsics {
        let (width, height) = self.size.unwrap_or((width, height));
        Intrinsics {
            width,
            height,
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::scratch::ScratchDir;

    #[test]
    fn parses_the_flag() {
        let spec = IntrinsicsSpec::from_arg("585,585,320,240").unwrap();
        assert_eq!(
            spec,
            IntrinsicsSpec {
                fx: 585.0,
                fy: 585.0,
                cx: 320.0,
                cy: 240.0,
                size: None
            }
        );
        let k = IntrinsicsSpec::from_arg(" 517.3, 516.5 ,318.6,255.3,640,480").unwrap();
        assert_eq!(k.size, Some((640, 480)));
        assert_eq!(k.resolve(1, 1).width, 640);
        assert_eq!(spec.resolve(320, 240).height, 240);
        for (arg, expected) in [
            ("585,585,320", "found 3 numbers"),
            ("585,x,320,240", "\"x\" is not a finite number"),
            ("0,585,320,240", "focal lengths must be positive"),
            (
                "585,585,320,240,640.5,480",
                "not two positive whole numbers",
            ),
            ("585,585,320,240,0,480", "not two positive whole numbers"),
        ] {
            let e = IntrinsicsSpec::from_arg(arg).unwrap_err().to_string();
            assert!(
                e.starts_with("invalid --intrinsics: ") && e.contains(expected),
                "{e}"
            );
        }
    }

    #[test]
    fn reads_both_file_formats() {
        let dir = ScratchDir::new("intrinsics");
        let k = dir.path().join("camera-intrinsics.txt");
        std::fs::write(
            &k,
            "5.85e+02 0.0 3.2e+02\n0 5.86e+02 2.4e+02\n0.000000000000000000e+00 0 1.0\n",
        )
        .unwrap();
        let spec = IntrinsicsSpec::from_arg(k.to_str().unwrap()).unwrap();
        assert_eq!(
            (spec.fx, spec.fy, spec.cx, spec.cy, spec.size),
            (585.0, 586.0, 320.0, 240.0, None)
        );

        let line = dir.path().join("intrinsics.txt");
        std::fs::write(
            &line,
            "# width height fx fy cx cy\n640 480 525 525 319.5 239.5\n",
        )
        .unwrap();
        let spec = IntrinsicsSpec::read_file(&line).unwrap();
        assert_eq!(spec.size, Some((640, 480)));
        assert_eq!(spec.cx, 319.5);

        for (body, expected) in [
            ("585 0 320\n0 585 240\n0 0 2\n", "K must be"),
            ("585 1 320\n0 585 240\n0 0 1\n", "K must be"),
            ("585 0 320\n0 585 240\n0\n", "found 7 numbers"),
            ("585 0 320 0 585\n", "found 5 numbers"),
            ("640 480 525 525 319.5 zz\n", "line 1: \"zz\""),
        ] {
            std::fs::write(&line, body).unwrap();
            let e = IntrinsicsSpec::read_file(&line).unwrap_err().to_string();
            assert!(
                e.starts_with(&line.display().to_string()) && e.contains(expected),
                "{e}"
            );
        }
        let missing = dir.path().join("none.txt");
        let e = IntrinsicsSpec::from_arg(missing.to_str().unwrap()).unwrap_err();
        assert!(matches!(e, Error::Io { ref path, .. } if path == &missing));
    }
}
