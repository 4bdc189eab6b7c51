//! A frame's record as stored: JSON, with poses as their exact `f32`s (JSON
//! numbers written shortest-exact and read back to the same bits).

use crate::camera::Pose;
use crate::map::IntegrateReport;
use crate::session::{FrameRecord, TrackRecord};
use crate::track::LostReason;
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
        "track": r.track.as_ref().map(track_json),
    })
    .to_string()
}

fn track_json(t: &TrackRecord) -> Value {
    let lost = t.lost.map(|l| match l {
        LostReason::EmptyModel => json!(["empty_model", 0.0]),
        LostReason::FewInliers(x) => json!(["few_inliers", x]),
        LostReason::LargeError(x) => json!(["large_error", x]),
        LostReason::Contradicted(x) => json!(["contradicted", x]),
        LostReason::Ambiguous(n) => json!(["ambiguous", n]),
        LostReason::Jump(x) => json!(["jump", x]),
        LostReason::SeenEmpty(x) => json!(["seen_empty", x]),
    });
    json!({
        "ms": t.ms,
        "inlier_fraction": t.inlier_fraction,
        "residual_mm": t.residual_mm,
        "conditioning": t.conditioning,
        "iterations": t.iterations,
        "weak_directions": t.weak_directions,
        "weak_axes": t.weak_axes,
        "relocalised": t.relocalised,
        "recovered": t.recovered,
        "held": t.held,
        "lost": lost,
    })
}

fn track_from(v: &Value) -> Result<TrackRecord, String> {
    let number = |k: &str| v[k].as_f64().ok_or_else(|| format!("track: no {k}"));
    let small = |k: &str| {
        v[k].as_u64()
            .and_then(|n| u8::try_from(n).ok())
            .ok_or_else(|| format!("track: no {k}"))
    };
    let lost = match &v["lost"] {
        Value::Null => None,
        l => {
            let x = l[1].as_f64().ok_or("track: lost without a value")?;
            Some(match l[0].as_str() {
                Some("empty_model") => LostReason::EmptyModel,
                Some("few_inliers") => LostReason::FewInliers(x),
                Some("large_error") => LostReason::LargeError(x),
                Some("contradicted") => LostReason::Contradicted(x),
                Some("ambiguous") => LostReason::Ambiguous(x as u8),
                Some("jump") => LostReason::Jump(x as f32),
                Some("seen_empty") => LostReason::SeenEmpty(x),
                _ => return Err("track: unknown reason".into()),
            })
        }
    };
    Ok(TrackRecord {
        ms: number("ms")?,
        inlier_fraction: number("inlier_fraction")?,
        residual_mm: number("residual_mm")?,
        conditioning: number("conditioning")?,
        iterations: v["iterations"].as_u64().ok_or("track: no iterations")? as usize,
        weak_directions: small("weak_directions")?,
        weak_axes: small("weak_axes")?,
        relocalised: v["relocalised"].as_bool().ok_or("track: no relocalised")?,
        // Absent from records saved before the search started in the frame
        // following lost: none was found there.
        recovered: flag(v, "recovered")?,
        // Absent from records saved before followed frames were held.
        held: flag(v, "held")?,
        lost,
    })
}

/// Boolean `key` of a track record, false when absent (a record saved
/// before the key was written); an error when present but not a boolean.
fn flag(v: &Value, key: &str) -> Result<bool, String> {
    match &v[key] {
        Value::Null => Ok(false),
        Value::Bool(b) => Ok(*b),
        other => Err(format!("track: {key} is {other}, not true or false")),
    }
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
        track: match &v["track"] {
            Value::Null => None,
            t => Some(track_from(t)?),
        },
    })
}

/// A pose as 12 numbers: rotation columns, then the camera centre.
pub fn pose_array(p: &Pose) -> [f32; 12] {
    let r = p.rotation.to_cols_array();
    let t = p.translation;
    [
        r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], t.x, t.y, t.z,
    ]
}

/// The pose of [`pose_array`]'s numbers.
pub fn pose_from(v: &Value) -> Result<Pose, String> {
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
        let tracked = FrameRecord {
            track: Some(TrackRecord {
                ms: 2.5,
                inlier_fraction: 0.87,
                residual_mm: 3.1,
                conditioning: 0.02,
                iterations: 14,
                weak_directions: 1,
                weak_axes: 4,
                relocalised: true,
                recovered: false,
                lost: Some(LostReason::Jump(0.41)),
                held: false,
            }),
            ..r
        };
        assert_eq!(decode(encode(&tracked).as_bytes()).unwrap(), tracked);
        let mut held = tracked.clone();
        held.track.as_mut().expect("tracked").held = true;
        assert_eq!(decode(encode(&held).as_bytes()).unwrap(), held);
        // Older records lack the flags; a malformed one is an error.
        let mut older: Value = serde_json::from_str(&encode(&held)).unwrap();
        older["track"].as_object_mut().unwrap().remove("held");
        let back = decode(older.to_string().as_bytes()).unwrap();
        assert!(!back.track.expect("tracked").held);
        older["track"]["held"] = json!(1);
        assert!(decode(older.to_string().as_bytes()).is_err());
        let reasons = [
            LostReason::EmptyModel,
            LostReason::FewInliers(0.2),
            LostReason::LargeError(0.03),
            LostReason::Contradicted(0.6),
            LostReason::Ambiguous(2),
            LostReason::SeenEmpty(0.04),
        ];
        for lost in reasons {
            let mut other = tracked.clone();
            other.track.as_mut().expect("tracked").lost = Some(lost);
            assert_eq!(decode(encode(&other).as_bytes()).unwrap(), other);
        }
        assert!(decode(b"{\"frame\": 1}").is_err());
    }
}
