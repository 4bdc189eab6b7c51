//! Wavefront OBJ files: positions (with the common `v x y z r g b` colour
//! extension), normals and polygon faces. Texture coordinates, groups and
//! materials are ignored because [`Mesh`] has nowhere to keep them.

use crate::atomic::write_atomic;
use crate::error::{Error, Result};
use crate::mesh::Mesh;
use glam::Vec3;
use std::io::Write;
use std::path::Path;

/// Reads an OBJ file.
pub fn read_obj(path: &Path) -> Result<Mesh> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    read_obj_from_bytes(&bytes, path)
}

/// Parses an OBJ file held in memory; `path_for_errors` only labels error messages.
///
/// Polygons are fan-triangulated. Vertex colours are kept only when every
/// vertex has them. OBJ normals belong to face corners while [`Mesh`] normals
/// belong to vertices, so a vertex takes the normal of the last corner that
/// names it; vertices no corner gives a normal get zero.
pub fn read_obj_from_bytes(bytes: &[u8], path_for_errors: &Path) -> Result<Mesh> {
    let path = path_for_errors;
    let mut mesh = Mesh::default();
    let mut all_colored = true;
    let mut vn: Vec<Vec3> = Vec::new();
    // Index into `vn` for each position, u32::MAX for none; grown on demand.
    let mut normal_of: Vec<u32> = Vec::new();
    let mut faces_use_normals = false;

    for (line_index, raw) in bytes.split(|&b| b == b'\n').enumerate() {
        let line_no = line_index + 1;
        let fail = |message: String| Error::format(path, format!("line {line_no}: {message}"));
        let content = raw.split(|&b| b == b'#').next().unwrap_or(raw);
        let mut tokens = content
            .split(|b| b.is_ascii_whitespace())
            .filter(|t| !t.is_empty());
        match tokens.next() {
            Some(b"v") => {
                let mut values = [0.0f32; 6];
                let mut n = 0;
                for token in tokens.take(6) {
                    values[n] = number(token).map_err(&fail)?;
                    n += 1;
                }
                if n < 3 {
                    return Err(fail("'v' needs x y z".to_string()));
                }
                let p = Vec3::new(values[0], values[1], values[2]);
                if !p.is_finite() {
                    return Err(fail(format!("non-finite vertex {p}")));
                }
                mesh.positions.push(p);
                // Four or five values are x y z w [..]; six or more carry a colour.
                if n >= 6 && all_colored {
                    mesh.colors
                        .push(std::array::from_fn(|c| (values[3 + c] * 255.0 + 0.5) as u8));
                } else {
                    all_colored = false;
                }
            }
            Some(b"vn") => {
                let mut values = [0.0f32; 3];
                for v in &mut values {
                    let token = tokens
                        .next()
                        .ok_or_else(|| fail("'vn' needs x y z".to_string()))?;
                    *v = number(token).map_err(&fail)?;
                }
                vn.push(Vec3::from_array(values));
            }
            Some(b"f") => {
                let mut first = 0;
                let mut prev = 0;
                for (corner, token) in tokens.enumerate() {
                    let mut parts = token.split(|&b| b == b'/');
                    let position = parts.next().unwrap_or(token);
                    let p = resolve(position, mesh.positions.len(), "vertex").map_err(&fail)?;
                    let normal = parts.nth(1).filter(|t| !t.is_empty());
                    if let Some(normal) = normal {
                        let n = resolve(normal, vn.len(), "normal").map_err(&fail)?;
                        faces_use_normals = true;
                        if normal_of.len() < mesh.positions.len() {
                            normal_of.resize(mesh.positions.len(), u32::MAX);
                        }
                        normal_of[p as usize] = n;
                    }
                    match corner {
                        0 => first = p,
                        1 => {}
                        _ => mesh.triangles.push([first, prev, p]),
                    }
                    prev = p;
                }
            }
            // vt, o, g, s, usemtl, mtllib, l, p and anything else carry
            // nothing a Mesh can hold.
            _ => {}
        }
    }

    if !all_colored {
        mesh.colors.clear();
    }
    if faces_use_normals {
        mesh.normals = (0..mesh.positions.len())
            .map(|i| match normal_of.get(i) {
                Some(&n) if n != u32::MAX => vn[n as usize],
                _ => Vec3::ZERO,
            })
            .collect();
    }
    Ok(mesh)
}

fn number(token: &[u8]) -> Result<f32, String> {
    std::str::from_utf8(token)
        .ok()
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| format!("'{}' is not a number", String::from_utf8_lossy(token)))
}

/// Turns a 1-based or negative (counted back from the latest) OBJ index into
/// a 0-based one, given how many items are defined so far.
fn resolve(token: &[u8], defined: usize, what: &str) -> Result<u32, String> {
    let text = String::from_utf8_lossy(token);
    let i: i64 = text
        .parse()
        .map_err(|_| format!("'{text}' is not a {what} index"))?;
    let zero_based = match i {
        0 => return Err(format!("{what} index 0 (OBJ indices start at 1)")),
        i if i > 0 => i - 1,
        i => defined as i64 + i,
    };
    if zero_based < 0 || zero_based >= defined as i64 {
        return Err(format!(
            "{what} index {i} out of range ({defined} defined so far)"
        ));
    }
    Ok(zero_based as u32)
}

/// Writes `mesh` to `path` as OBJ, atomically (see [`write_atomic`]).
pub fn write_obj(path: &Path, mesh: &Mesh) -> Result<()> {
    mesh.check().map_err(|m| Error::parameter("mesh", m))?;
    write_atomic(path, |w| write_obj_to(w, mesh))
}

/// Writes `mesh` as OBJ to any writer: `v x y z [r g b]` with colours as
/// 0..1 floats, `vn` lines if the mesh has normals, and 1-based faces
/// (`f a//a b//b c//c` with normals, `f a b c` without). An inconsistent mesh
/// is an `InvalidInput` error, since the file would not read back.
pub fn write_obj_to<W: Write>(mut w: W, mesh: &Mesh) -> std::io::Result<()> {
    mesh.check()
        .map_err(|m| std::io::Error::new(std::io::ErrorKind::InvalidInput, m))?;
    // Formatting into one reusable buffer handed over in large blocks keeps
    // the writer's per-call overhead out of the loop.
    const FLUSH_AT: usize = 1 << 20;
    let mut buf: Vec<u8> = Vec::with_capacity(FLUSH_AT + 256);
    buf.extend_from_slice(b"# written by depthmesh\n");
    for (i, p) in mesh.positions.iter().enumerate() {
        // `{}` prints the shortest text that parses back to the same f32.
        write!(buf, "v {} {} {}", p.x, p.y, p.z)?;
        if let Some(&[r, g, b]) = mesh.colors.get(i) {
            let [r, g, b] = [r, g, b].map(|c| c as f32 / 255.0);
            write!(buf, " {r} {g} {b}")?;
        }
        buf.push(b'\n');
        if buf.len() >= FLUSH_AT {
            w.write_all(&buf)?;
            buf.clear();
        }
    }
    for n in &mesh.normals {
        writeln!(buf, "vn {} {} {}", n.x, n.y, n.z)?;
        if buf.len() >= FLUSH_AT {
            w.write_all(&buf)?;
            buf.clear();
        }
    }
    let with_normals = !mesh.normals.is_empty();
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| i as u64 + 1);
        if with_normals {
            writeln!(buf, "f {a}//{a} {b}//{b} {c}//{c}")?;
        } else {
            writeln!(buf, "f {a} {b} {c}")?;
        }
        if buf.len() >= FLUSH_AT {
            w.write_all(&buf)?;
            buf.clear();
        }
    }
    w.write_all(&buf)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::scratch::ScratchDir;

    fn parse(text: &str) -> Result<Mesh> {
        read_obj_from_bytes(text.as_bytes(), Path::new("test.obj"))
    }

    fn err(text: &str) -> String {
        let e = parse(text).unwrap_err();
        let message = e.to_string();
        assert!(matches!(e, Error::Format { .. }), "{message}");
        assert!(message.contains("test.obj"), "{message}");
        message
    }

    fn sample() -> Mesh {
        Mesh {
            positions: vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(1.5, -2.25, 3.125),
                Vec3::new(0.1, 0.2, 0.3),
                Vec3::new(-1e-7, 12345.678, 1e30),
            ],
            normals: vec![Vec3::X, Vec3::Y, Vec3::new(0.6, 0.0, 0.8), Vec3::NEG_Z],
            colors: vec![[0, 0, 0], [255, 128, 1], [7, 200, 99], [255, 255, 255]],
            triangles: vec![[0, 1, 2], [2, 1, 3], [3, 0, 2]],
        }
    }

    fn to_text(mesh: &Mesh) -> String {
        let mut out = Vec::new();
        write_obj_to(&mut out, mesh).unwrap();
        String::from_utf8(out).unwrap()
    }

    #[test]
    fn round_trip_is_exact() {
        let full = sample();
        assert_eq!(parse(&to_text(&full)).unwrap(), full);
        let bare = Mesh {
            normals: Vec::new(),
            colors: Vec::new(),
            ..sample()
        };
        let text = to_text(&bare);
        assert!(text.contains("\nf 1 2 3\n"), "{text}");
        assert_eq!(parse(&text).unwrap(), bare);
    }

    #[test]
    fn every_colour_survives_a_round_trip() {
        let mesh = Mesh {
            positions: vec![Vec3::ZERO; 256],
            colors: (0..=255u8).map(|c| [c, 255 - c, c / 2]).collect(),
            ..Mesh::default()
        };
        assert_eq!(parse(&to_text(&mesh)).unwrap(), mesh);
    }

    #[test]
    fn file_round_trip() {
        let dir = ScratchDir::new("obj-file");
        let path = dir.path().join("mesh.obj");
        write_obj(&path, &sample()).unwrap();
        assert_eq!(read_obj(&path).unwrap(), sample());
        assert_eq!(dir.entries(), vec!["mesh.obj".to_string()]);
    }

    #[test]
    fn face_forms_negative_indices_and_polygons() {
        let text = "# a comment\r\nmtllib scene.mtl\no thing\ng group\ns off\n\
            v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0 # trailing comment\n\
            vt 0 0\nvt 1 1\nvn 0 0 1\nvn 0 0 -1\nusemtl red\n\
            f 1//1 2//1 3//2\r\n\
            f -4/1/2 -2/2/2 -1/1/2\n\
            f 1/1 2/2 3/1 4/2\n\
            f 1 2\n";
        let mesh = parse(text).unwrap();
        assert_eq!(
            mesh.triangles,
            vec![[0, 1, 2], [0, 2, 3], [0, 1, 2], [0, 2, 3]]
        );
        // The last corner naming a vertex decides its normal; vertex 1 is only
        // named in the first face.
        assert_eq!(mesh.normals, vec![-Vec3::Z, Vec3::Z, -Vec3::Z, -Vec3::Z]);
        assert!(mesh.colors.is_empty());
    }

    #[test]
    fn partial_colours_and_w_are_dropped() {
        let mesh = parse("v 0 0 0 1 0 0\nv 1 0 0 1.0\nv 0 1 0\nf 1 2 3\n").unwrap();
        assert!(mesh.colors.is_empty());
        assert!(mesh.normals.is_empty());
        assert_eq!(mesh.positions[1], Vec3::X);
        let colored = parse("v 0 0 0 1 0 0\nv 1 0 0 0 1 0.5\n").unwrap();
        assert_eq!(colored.colors, vec![[255, 0, 0], [0, 255, 128]]);
    }

    #[test]
    fn malformed_files_name_the_line() {
        assert!(err("v 0 0 0\nv 1 x 0\n").contains("line 2: 'x' is not a number"));
        assert!(err("v 0 0\n").contains("line 1: 'v' needs x y z"));
        assert!(err("v 0 0 inf\n").contains("line 1: non-finite"));
        assert!(err("vn 0 0\n").contains("line 1: 'vn' needs x y z"));
        let tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
        assert!(err(&format!("{tri}f 1 2 4\n")).contains("line 4: vertex index 4 out of range"));
        assert!(err(&format!("{tri}f 1 2 -4\n")).contains("vertex index -4 out of range"));
        assert!(err(&format!("{tri}f 0 1 2\n")).contains("line 4: vertex index 0"));
        assert!(err(&format!("{tri}f 1 2 three\n")).contains("'three' is not a vertex index"));
        assert!(err(&format!("{tri}f 1//1 2//1 3//1\n")).contains("normal index 1 out of range"));
        assert!(err(&format!("{tri}f 1 2 99999999999999999999\n")).contains("line 4"));
    }

    #[test]
    fn garbage_never_panics() {
        let clean = to_text(&sample()).into_bytes();
        for bytes in crate::mesh::corrupted_copies(&clean, 0x2545_f491_4f6c_dd1d, 2000) {
            if let Err(e) = read_obj_from_bytes(&bytes, Path::new("test.obj")) {
                assert!(e.to_string().contains("test.obj"));
            }
        }
        for len in 0..clean.len() {
            let _ = read_obj_from_bytes(&clean[..len], Path::new("test.obj"));
        }
    }
}
