//! Binary glTF 2.0 (`.glb`): what game engines and viewers load directly.
//!
//! A file is a 12-byte header, a JSON chunk and a BIN chunk, each 4-byte
//! aligned. Each node holds one mesh with float positions (with the min/max
//! the specification requires), float normals, colours and indices — 16-bit
//! when the mesh has at most 65,535 vertices, 32-bit otherwise. Node
//! transforms are identity: vertices are in the file's global coordinates,
//! so separately imported chunks line up.
//!
//! glTF colours are linear while [`Mesh`] colours are sRGB bytes; colours are
//! stored as normalised 16-bit linear values, which keep every sRGB byte
//! distinct (8-bit linear would merge the dark ones) and read back exactly.

use crate::atomic::write_atomic;
use crate::error::{Error, Result};
use crate::mesh::Mesh;
use glam::Vec3;
use serde_json::{json, Value};
use std::io::Write;
use std::path::Path;

/// One node of a GLB file.
#[derive(Clone, Copy, Debug)]
pub struct GlbNode<'a> {
    /// Node and mesh name.
    pub name: &'a str,
    /// The geometry.
    pub mesh: &'a Mesh,
    /// A collision mesh: written with positions only, without material, under
    /// a `collision` parent node and flagged `"extras": {"collision": true}`
    /// so engines and tools can tell it from what is drawn.
    pub collision: bool,
}

/// A node read back from a GLB file.
#[derive(Clone, Debug, PartialEq)]
pub struct GlbMesh {
    /// Node name (empty if none).
    pub name: String,
    /// Whether the node is flagged as collision geometry.
    pub collision: bool,
    /// The node's primitives joined into one mesh.
    pub mesh: Mesh,
}

const MAGIC: u32 = 0x4654_6C67; // "glTF"
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;
const FLOAT: u32 = 5126;
const UNSIGNED_BYTE: u32 = 5121;
const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;
const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;

/// Writes `nodes` as one GLB file, atomically. Every mesh must be consistent
/// (see [`Mesh::check`]) and have at least one triangle.
pub fn write_glb(path: &Path, nodes: &[GlbNode]) -> Result<()> {
    let bytes = glb_bytes(nodes)?;
    write_atomic(path, |w| w.write_all(&bytes))
}

/// The bytes of a GLB file holding `nodes`.
pub fn glb_bytes(nodes: &[GlbNode]) -> Result<Vec<u8>> {
    if nodes.is_empty() {
        return Err(Error::parameter("mesh", "nothing to write (no nodes)"));
    }
    let mut bin: Vec<u8> = Vec::new();
    let mut views: Vec<Value> = Vec::new();
    let mut accessors: Vec<Value> = Vec::new();
    let mut meshes: Vec<Value> = Vec::new();
    let mut json_nodes: Vec<Value> = Vec::new();
    let mut scene_nodes: Vec<usize> = Vec::new();
    let mut collision_nodes: Vec<usize> = Vec::new();
    // Appends one tightly packed buffer view and its accessor; returns the accessor index.
    let mut add = |data: &[u8], target: u32, accessor: Value| -> usize {
        views.push(json!({
            "buffer": 0,
            "byteOffset": bin.len(),
            "byteLength": data.len(),
            "target": target,
        }));
        bin.extend_from_slice(data);
        // The next view must start 4-byte aligned for any component type.
        bin.resize(bin.len().next_multiple_of(4), 0);
        let mut accessor = accessor;
        accessor["bufferView"] = json!(views.len() - 1);
        accessors.push(accessor);
        accessors.len() - 1
    };
    for node in nodes {
        let mesh = node.mesh;
        mesh.check()
            .map_err(|m| Error::parameter(format!("mesh {}", node.name), m))?;
        if mesh.is_empty() {
            return Err(Error::parameter(
                format!("mesh {}", node.name),
                "has no triangles (glTF accessors cannot be empty)",
            ));
        }
        let n = mesh.vertex_count();
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        let mut data = Vec::with_capacity(12 * n);
        for p in &mesh.positions {
            lo = lo.min(*p);
            hi = hi.max(*p);
            data.extend(p.to_array().iter().flat_map(|v| v.to_le_bytes()));
        }
        let mut attributes = serde_json::Map::new();
        attributes.insert(
            "POSITION".into(),
            json!(add(
                &data,
                ARRAY_BUFFER,
                json!({"componentType": FLOAT, "count": n, "type": "VEC3",
                       "min": lo.to_array(), "max": hi.to_array()})
            )),
        );
        if !node.collision && !mesh.normals.is_empty() {
            let data: Vec<u8> = mesh
                .normals
                .iter()
                // glTF requires unit normals; a degenerate vertex has none.
                // Unit ones are kept bit for bit.
                .map(|&n| {
                    if (n.length_squared() - 1.0).abs() < 1e-5 {
                        n
                    } else {
                        n.try_normalize().unwrap_or(Vec3::Y)
                    }
                })
                .flat_map(|n| n.to_array())
                .flat_map(|v| v.to_le_bytes())
                .collect();
            attributes.insert(
                "NORMAL".into(),
                json!(add(
                    &data,
                    ARRAY_BUFFER,
                    json!({"componentType": FLOAT, "count": n, "type": "VEC3"})
                )),
            );
        }
        if !node.collision && !mesh.colors.is_empty() {
            let data: Vec<u8> = mesh
                .colors
                .iter()
                .flat_map(|c| {
                    let [r, g, b] = c.map(|v| srgb_byte_to_linear_u16(v).to_le_bytes());
                    [r, g, b, u16::MAX.to_le_bytes()]
                })
                .flatten()
                .collect();
            attributes.insert(
                "COLOR_0".into(),
                json!(add(
                    &data,
                    ARRAY_BUFFER,
                    json!({"componentType": UNSIGNED_SHORT, "normalized": true,
                           "count": n, "type": "VEC4"})
                )),
            );
        }
        // 65,535 is the primitive-restart value glTF forbids as a 16-bit index.
        let (data, component): (Vec<u8>, u32) = if n <= u16::MAX as usize {
            let data = mesh
                .triangles
                .iter()
                .flatten()
                .flat_map(|&i| (i as u16).to_le_bytes())
                .collect();
            (data, UNSIGNED_SHORT)
        } else {
            let data = mesh
                .triangles
                .iter()
                .flatten()
                .flat_map(|&i| i.to_le_bytes())
                .collect();
            (data, UNSIGNED_INT)
        };
        let indices = add(
            &data,
            ELEMENT_ARRAY_BUFFER,
            json!({"componentType": component, "count": 3 * mesh.triangle_count(),
                   "type": "SCALAR"}),
        );
        let mut primitive = json!({"attributes": attributes, "indices": indices, "mode": 4});
        let mut json_node = json!({"name": node.name, "mesh": meshes.len()});
        if node.collision {
            json_node["extras"] = json!({"collision": true});
            collision_nodes.push(json_nodes.len());
        } else {
            primitive["material"] = json!(0);
            scene_nodes.push(json_nodes.len());
        }
        meshes.push(json!({"name": node.name, "primitives": [primitive]}));
        json_nodes.push(json_node);
    }
    if !collision_nodes.is_empty() {
        scene_nodes.push(json_nodes.len());
        json_nodes.push(json!({"name": "collision", "children": collision_nodes}));
    }
    let mut doc = json!({
        "asset": {"version": "2.0", "generator": "depthmesh"},
        "scene": 0,
        "scenes": [{"nodes": scene_nodes}],
        "nodes": json_nodes,
        "meshes": meshes,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
    });
    if collision_nodes.len() < nodes.len() {
        // Vertex colours multiply the base colour; glTF's default material is
        // metallic, which would render a scan dark. Scans are single surfaces
        // seen from both sides.
        doc["materials"] = json!([{
            "name": "vertex colours",
            "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0],
                                     "metallicFactor": 0.0, "roughnessFactor": 1.0},
            "doubleSided": true,
        }]);
    }
    let mut text = serde_json::to_vec(&doc).expect("JSON values serialise");
    // JSON pads with spaces, BIN with zeros (glTF 2.0, section 4.4.3).
    text.resize(text.len().next_multiple_of(4), b' ');
    let total = 12 + 8 + text.len() + 8 + bin.len();
    let total = u32::try_from(total)
        .map_err(|_| Error::parameter("mesh", "too large for one GLB file (4 GiB)"))?;
    let mut out = Vec::with_capacity(total as usize);
    for word in [MAGIC, 2, total, text.len() as u32, CHUNK_JSON] {
        out.extend(word.to_le_bytes());
    }
    out.extend(&text);
    out.extend((bin.len() as u32).to_le_bytes());
    out.extend(CHUNK_BIN.to_le_bytes());
    out.extend(&bin);
    Ok(out)
}

/// Reads the meshes of a GLB file, one per node that has a mesh.
pub fn read_glb(path: &Path) -> Result<Vec<GlbMesh>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    read_glb_from_bytes(&bytes).map_err(|m| Error::format(path, m))
}

/// Parses a GLB file held in memory.
///
/// Reads triangle primitives with float positions and normals, colours of any
/// glTF colour type, and indices of any type, from nodes without transforms
/// (the layout depthmesh writes and most exporters of scans use). Anything
/// else is an error, rather than a silently misplaced mesh.
pub fn read_glb_from_bytes(bytes: &[u8]) -> Result<Vec<GlbMesh>, String> {
    let word = |at: usize| -> Result<u32, String> {
        bytes
            .get(at..at + 4)
            .map(|b| u32::from_le_bytes(b.try_into().expect("4 bytes")))
            .ok_or_else(|| "file ends inside the GLB header".to_string())
    };
    if word(0)? != MAGIC {
        return Err("not a GLB file (no 'glTF' magic)".into());
    }
    if word(4)? != 2 {
        return Err(format!("GLB version {} (only 2 is supported)", word(4)?));
    }
    let json_len = word(12)? as usize;
    if word(16)? != CHUNK_JSON || bytes.len() < 20 + json_len {
        return Err("first chunk is not a complete JSON chunk".into());
    }
    let doc: Value = serde_json::from_slice(&bytes[20..20 + json_len])
        .map_err(|e| format!("JSON chunk: {e}"))?;
    let bin_at = 20 + json_len;
    let bin: &[u8] = if bytes.len() >= bin_at + 8 && word(bin_at + 4)? == CHUNK_BIN {
        let len = word(bin_at)? as usize;
        bytes
            .get(bin_at + 8..bin_at + 8 + len)
            .ok_or("BIN chunk is truncated")?
    } else {
        &[]
    };
    let reader = Reader { doc: &doc, bin };
    let mut out = Vec::new();
    for (i, node) in array(&doc, "nodes").iter().enumerate() {
        let Some(mesh_index) = node.get("mesh") else {
            continue;
        };
        if ["matrix", "translation", "rotation", "scale"]
            .iter()
            .any(|k| node.get(*k).is_some())
        {
            return Err(format!("node {i} has a transform (not supported)"));
        }
        let mesh_json = index(mesh_index)
            .and_then(|m| array(&doc, "meshes").get(m))
            .ok_or(format!("node {i}: bad mesh index"))?;
        let mut mesh = Mesh::default();
        for p in array(mesh_json, "primitives") {
            mesh.append(&reader.primitive(p).map_err(|e| format!("node {i}: {e}"))?);
        }
        out.push(GlbMesh {
            name: node["name"].as_str().unwrap_or_default().to_string(),
            collision: node["extras"]["collision"].as_bool() == Some(true),
            mesh,
        });
    }
    Ok(out)
}

fn array<'a>(v: &'a Value, key: &str) -> &'a [Value] {
    v.get(key)
        .and_then(Value::as_array)
        .map_or(&[], Vec::as_slice)
}

fn index(v: &Value) -> Option<usize> {
    v.as_u64().map(|i| i as usize)
}

/// Decodes accessors from the BIN chunk.
struct Reader<'a> {
    doc: &'a Value,
    bin: &'a [u8],
}

impl Reader<'_> {
    fn primitive(&self, p: &Value) -> Result<Mesh, String> {
        if p.get("mode").and_then(Value::as_u64).unwrap_or(4) != 4 {
            return Err("only triangle primitives (mode 4) are supported".into());
        }
        let attribute = |name: &str| p["attributes"].get(name).map(|a| self.accessor(a));
        let vec3 =
            |values: Vec<Vec<f32>>| values.iter().map(|v| Vec3::new(v[0], v[1], v[2])).collect();
        let positions: Vec<Vec3> = vec3(attribute("POSITION").ok_or("no POSITION")??);
        let n = positions.len();
        let normals: Vec<Vec3> = attribute("NORMAL")
            .transpose()?
            .map(vec3)
            .unwrap_or_default();
        let colors = attribute("COLOR_0")
            .transpose()?
            .map(|c| {
                c.iter()
                    .map(|v| [0, 1, 2].map(|k| linear_to_srgb_byte(v[k])))
                    .collect()
            })
            .unwrap_or_default();
        let flat: Vec<u32> = match p.get("indices") {
            Some(a) => self.accessor(a)?.iter().map(|v| v[0] as u32).collect(),
            None => (0..n as u32).collect(),
        };
        if !flat.len().is_multiple_of(3) {
            return Err(format!(
                "{} indices is not a whole number of triangles",
                flat.len()
            ));
        }
        let mesh = Mesh {
            positions,
            normals,
            colors,
            triangles: flat.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
        };
        mesh.check()?;
        Ok(mesh)
    }

    /// An accessor's elements as floats (normalised integers scaled to 0..1).
    fn accessor(&self, a: &Value) -> Result<Vec<Vec<f32>>, String> {
        let a = index(a)
            .and_then(|i| array(self.doc, "accessors").get(i))
            .ok_or("bad accessor index")?;
        let count = a["count"].as_u64().ok_or("accessor without count")? as usize;
        let width = match a["type"].as_str() {
            Some("SCALAR") => 1,
            Some("VEC2") => 2,
            Some("VEC3") => 3,
            Some("VEC4") => 4,
            other => return Err(format!("unsupported accessor type {other:?}")),
        };
        let component = a["componentType"].as_u64().unwrap_or(0) as u32;
        let (size, scale) = match component {
            FLOAT => (4, 1.0),
            UNSIGNED_BYTE => (1, 255.0),
            UNSIGNED_SHORT => (2, 65535.0),
            UNSIGNED_INT => (4, 1.0),
            other => return Err(format!("unsupported component type {other}")),
        };
        let scale = if a["normalized"].as_bool() == Some(true) {
            1.0 / scale
        } else {
            1.0
        };
        let view = index(&a["bufferView"])
            .and_then(|i| array(self.doc, "bufferViews").get(i))
            .ok_or("accessor without buffer view (sparse accessors are not supported)")?;
        let start = view["byteOffset"].as_u64().unwrap_or(0) as usize
            + a["byteOffset"].as_u64().unwrap_or(0) as usize;
        let stride = view["byteStride"]
            .as_u64()
            .map_or(size * width, |s| s as usize);
        let end = if count == 0 {
            start
        } else {
            start + (count - 1) * stride + size * width
        };
        let data = self
            .bin
            .get(start..end)
            .ok_or("accessor reaches past the BIN chunk")?;
        Ok((0..count)
            .map(|e| {
                (0..width)
                    .map(|k| {
                        let at = e * stride + k * size;
                        let b = &data[at..at + size];
                        match (component, size) {
                            (FLOAT, _) => f32::from_le_bytes(b.try_into().expect("4 bytes")),
                            (UNSIGNED_INT, _) => {
                                u32::from_le_bytes(b.try_into().expect("4 bytes")) as f32 * scale
                            }
                            (_, 2) => u16::from_le_bytes([b[0], b[1]]) as f32 * scale,
                            _ => b[0] as f32 * scale,
                        }
                    })
                    .collect()
            })
            .collect())
    }
}

/// sRGB byte to linear intensity in 0..65535 (IEC 61966-2-1).
fn srgb_byte_to_linear_u16(v: u8) -> u16 {
    let c = v as f64 / 255.0;
    let linear = if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    };
    (linear * 65535.0).round() as u16
}

/// Linear intensity in 0..1 to the nearest sRGB byte.
fn linear_to_srgb_byte(v: f32) -> u8 {
    let l = v.clamp(0.0, 1.0) as f64;
    let c = if l <= 0.0031308 {
        l * 12.92
    } else {
        1.055 * l.powf(1.0 / 2.4) - 0.055
    };
    (c * 255.0).round() as u8
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atomic::scratch::ScratchDir;

    /// A strip of `n` vertices with every attribute varying.
    fn strip(n: u32) -> Mesh {
        Mesh {
            positions: (0..n)
                .map(|i| Vec3::new(i as f32 * 0.5, (i % 2) as f32, -(i as f32) / 3.0))
                .collect(),
            normals: (0..n)
                .map(|i| Vec3::new(1.0, i as f32, 2.0).normalize())
                .collect(),
            colors: (0..n)
                .map(|i| {
                    [
                        (i % 256) as u8,
                        (i / 256 % 256) as u8,
                        255 - (i % 256) as u8,
                    ]
                })
                .collect(),
            triangles: (0..n - 2).map(|i| [i, i + 1, i + 2]).collect(),
        }
    }

    #[test]
    fn round_trips_positions_normals_colours_and_indices() {
        let dir = ScratchDir::new("glb-round-trip");
        let path = dir.path().join("m.glb");
        let small = strip(300);
        // Past 65,535 vertices the indices must be 32-bit.
        let large = strip(70_000);
        let collision = Mesh {
            normals: Vec::new(),
            colors: Vec::new(),
            ..strip(10)
        };
        let nodes = [
            GlbNode {
                name: "chunk_000",
                mesh: &small,
                collision: false,
            },
            GlbNode {
                name: "chunk_001",
                mesh: &large,
                collision: false,
            },
            GlbNode {
                name: "collision_000",
                mesh: &collision,
                collision: true,
            },
        ];
        write_glb(&path, &nodes).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes.len() % 4, 0);
        let back = read_glb(&path).unwrap();
        assert_eq!(back.len(), 3);
        for (node, read) in nodes.iter().zip(&back) {
            assert_eq!(read.name, node.name);
            assert_eq!(read.collision, node.collision);
            let (a, b) = (&read.mesh, node.mesh);
            assert_eq!(a.triangles, b.triangles, "{}", node.name);
            assert!(a.positions == b.positions, "{}", node.name);
            assert!(a.normals == b.normals, "{}", node.name);
            assert!(a.colors == b.colors, "{}", node.name);
        }
        let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
        let doc: Value = serde_json::from_slice(&bytes[20..20 + json_len]).unwrap();
        let index_type = |mesh: usize| {
            let a = doc["meshes"][mesh]["primitives"][0]["indices"]
                .as_u64()
                .unwrap() as usize;
            doc["accessors"][a]["componentType"].as_u64().unwrap() as u32
        };
        assert_eq!(index_type(0), UNSIGNED_SHORT);
        assert_eq!(index_type(1), UNSIGNED_INT);
        let position = doc["accessors"][0].clone();
        assert_eq!(position["min"], json!([0.0, 0.0, -(299.0f32 / 3.0)]));
        assert_eq!(position["max"], json!([149.5, 1.0, 0.0]));
    }

    #[test]
    fn every_srgb_byte_survives_linear_storage() {
        for v in 0..=255u8 {
            let linear = srgb_byte_to_linear_u16(v) as f32 / 65535.0;
            assert_eq!(linear_to_srgb_byte(linear), v);
        }
    }

    #[test]
    fn damaged_files_are_errors_naming_the_file() {
        let dir = ScratchDir::new("glb-damaged");
        let good = glb_bytes(&[GlbNode {
            name: "m",
            mesh: &strip(5),
            collision: false,
        }])
        .unwrap();
        let cases: [(&str, Vec<u8>); 3] = [
            ("text.glb", b"solid cube\nendsolid\n".to_vec()),
            ("short.glb", good[..good.len() - 8].to_vec()),
            ("header.glb", good[..10].to_vec()),
        ];
        for (name, bytes) in cases {
            let path = dir.path().join(name);
            std::fs::write(&path, bytes).unwrap();
            let e = read_glb(&path).unwrap_err();
            assert!(matches!(e, Error::Format { .. }), "{e}");
            assert!(e.to_string().contains(name), "{e}");
        }
    }

    #[test]
    fn empty_meshes_are_refused() {
        let e = glb_bytes(&[GlbNode {
            name: "m",
            mesh: &Mesh::default(),
            collision: false,
        }])
        .unwrap_err();
        assert!(e.to_string().contains("no triangles"), "{e}");
        assert!(glb_bytes(&[]).is_err());
    }
}
