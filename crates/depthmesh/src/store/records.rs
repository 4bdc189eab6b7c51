//! A frame's record as stored: JSON, with poses as their exact `f32`s (JSON
//! numbers written shortest-exact and read back to the same bits).

use crate::camera::Pose;
use crate::map::IntegrateReport;
use crate::session::FrameRecord;
use glam::{Mat3, Vec3};
use serde_json::{json, Value};
use std::sync::Mutex;

/// `r` as a JSON line.
pub fn encode(r: &FrameRecord) -> String {
    json!({
        "frame": r.frame,
        "timestamp": r.timestamp,
        "ms": r.ms,
        "pose": r.pose.as_ref().map(pose_array),
        "estimate": pose_array(&r.estimate),
        "new": r.report.new_elements,
        "removed": r.report.removed_elements,
        "extra": r.report.extra,
        "elements": r.total_elements,
        "vertices": r.total_vertices,
    })
    .to_string()
}

/// The record in `bytes`.
pub fn decode(bytes: &[u8]) -> Result<FrameRecord, String> {
    let v: Value = serde_json::from_slice(bytes).map_err(|e| e.to_string())?;
    let number = |k: &str| v[k].as_f64().ok_or_else(|| format!("no {k}"));
    let count = |k: &str| {
        v[k].as_u64()
            .map(|n| n as usize)
            .ok_or_else(|| format!("no {k}"))
    };
    let extra = v["extra"]
        .as_array()
        .ok_or("no extra")?
        .iter()
        .map(|e| {
            let name = e[0].as_str().ok_or("extra: no name")?;
            let value = e[1].as_f64().ok_or("extra: no value")?;
            Ok((intern(name), value))
        })
        .collect::<Result<Vec<_>, String>>()?;
    Ok(FrameRecord {
        frame: count("frame")?,
        timestamp: number("timestamp")?,
        ms: number("ms")?,
        pose: match &v["pose"] {
            Value::Null => None,
            p => Some(pose_from(p)?),
        },
        estimate: pose_from(&v["estimate"])?,
        report: IntegrateReport {
            new_elements: count("new")?,
            removed_elements: count("removed")?,
            extra,
        },
        total_elements: count("elements")?,
        total_vertices: v["vertices"].as_u64().map(|n| n as usize),
        track: None,
    })
}

fn pose_array(p: &Pose) -> [f32; 12] {
    let r = p.rotation.to_cols_array();
    let t = p.translation;
    [
        r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], t.x, t.y, t.z,
    ]
}

fn pose_from(v: &Value) -> Result<Pose, String> {
    let a: Vec<f32> = v
        .as_array()
        .filter(|a| a.len() == 12)
        .ok_or("a pose is 12 numbers")?
        .iter()
        .map(|x| x.as_f64().map(|x| x as f32).ok_or("a pose is 12 numbers"))
        .collect::<Result<_, _>>()?;
    Ok(Pose::new(
        Mat3::from_cols_slice(&a[..9]),
        Vec3::new(a[9], a[10], a[11]),
    ))
}

/// The names of a report's extra figures are `&'static str` (each back-end
/// names its own); names read back are kept once for the process.
fn intern(name: &str) -> &'static str {
    static NAMES: Mutex<Vec<&'static str>> = Mutex::new(Vec::new());
    let mut names = NAMES.lock().expect("names lock");
    if let Some(n) = names.iter().find(|n| **n == name) {
        return n;
    }
    let leaked: &'static str = Box::leak(name.to_string().into_boxed_str());
    names.push(leaked);
    leaked
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_record_comes_back_bit_for_bit() {
        let pose = Pose::new(
            Mat3::from_rotation_y(0.123_456_7),
            Vec3::new(0.1, -2.345_678_9, 1e-7),
        );
        let r = FrameRecord {
            frame: 42,
            timestamp: 1.234_567_890_123,
            ms: 3.25,
            pose: Some(pose),
            estimate: pose,
            report: IntegrateReport {
                new_elements: 512,
                removed_elements: 0,
                extra: vec![("blocks", 17.0), ("integrate_ms", 1.5)],
            },
            total_elements: 8704,
            total_vertices: None,
            track: None,
        };
        let back = decode(encode(&r).as_bytes()).unwrap();
        assert_eq!(back, r);
        assert!(decode(b"{\"frame\": 1}").is_err());
    }
}
