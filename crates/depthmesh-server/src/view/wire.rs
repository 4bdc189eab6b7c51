//! Viewer messages in binary: a part of the map, compact, and an image.
//!
//! A part (`DMV1`, little-endian):
//!
//! | offset | field |
//! |---|---|
//! | 0 | magic `DMV1` |
//! | 4 | key, 3 × i32 |
//! | 16 | flags, u32: bit 0 colours |
//! | 20 | vertices, u32 (0: the part is gone) |
//! | 24 | indices, u32 (3 per triangle) |
//! | 28 | origin, 3 × i32, in quanta |
//! | 40 | step, f32 (metres per quantum) |
//! | 44 | bytes of the encoded vertices, u32 |
//! | 48 | vertices, meshoptimizer's vertex codec; then indices, its index codec, to the end |
//!
//! A vertex is 12 bytes: its position as 3 × u16 quanta from `origin`
//! (and 2 bytes of padding), at `(origin + q) · step` metres, and its
//! colour as RGB(A). Positions lie on one grid for every part with the same
//! step, so the page finds a vertex that two parts share by its quanta and
//! joins them; it computes normals from the joined triangles. Sending
//! normals instead would cost a third of the bytes (measured on the
//! kitchen), for shading a viewer cannot tell apart. meshoptimizer's codecs (the ones glTF's `EXT_meshopt_compression`
//! uses; the page decodes them with meshoptimizer's own decoder) store
//! each byte column as deltas, so padding and constant columns cost almost
//! nothing. Vertices and triangles are first put in vertex-cache order
//! (the fast FIFO variant: it compresses as well here at a third of the
//! time), which the index codec compresses best.
//!
//! An image (`DMI1`): magic, kind u32 (see [`super::hub::ImageKind`]), then a JPEG.

use depthmesh::mesh::Mesh;
use depthmesh::session::view::PartKey;

/// Magic of a part message.
pub const PART_MAGIC: &[u8; 4] = b"DMV1";
/// Magic of an image message.
pub const IMAGE_MAGIC: &[u8; 4] = b"DMI1";

/// The finest quantum of a position: 1/2048 m (0.5 mm, an error of at
/// most 0.25 mm), under any depth sensor's noise and invisible at any
/// distance a map is looked at from, while coarse enough for the vertex
/// codec's deltas to stay small; parts larger than 32 m across get a
/// coarser one. (Downloads are exact: this is only the view.)
const FINEST_STEP: f32 = 1.0 / 2048.0;

/// A vertex on the wire.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
struct WireVertex {
    position: [u16; 4],
    color: [u8; 4],
}

/// The message for part `key` with triangles `mesh` (none: the part is gone).
pub fn encode_part(key: PartKey, mesh: &Mesh) -> Vec<u8> {
    let bounds = mesh.bounds();
    let step = if mesh.triangles.is_empty() {
        FINEST_STEP
    } else {
        (bounds.extent().max_element() / f32::from(u16::MAX - 1)).max(FINEST_STEP)
    };
    // The grid point at or below the part's lowest corner.
    let origin = if mesh.triangles.is_empty() {
        glam::IVec3::ZERO
    } else {
        (bounds.min / step).floor().as_ivec3()
    };
    let colors = mesh.colors.len() == mesh.positions.len() && !mesh.positions.is_empty();
    let vertices: Vec<WireVertex> = (0..mesh.positions.len())
        .map(|i| {
            let q = ((mesh.positions[i] / step).round().as_ivec3() - origin)
                .clamp(glam::IVec3::ZERO, glam::IVec3::splat(i32::from(u16::MAX)));
            let c = if colors { mesh.colors[i] } else { [0; 3] };
            WireVertex {
                position: [q.x as u16, q.y as u16, q.z as u16, 0],
                color: [c[0], c[1], c[2], 255],
            }
        })
        .collect();
    let flat: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
    let (vertex_bytes, index_bytes, vertex_count) = if flat.is_empty() {
        (Vec::new(), Vec::new(), 0)
    } else {
        let mut indices = meshopt::optimize_vertex_cache_fifo(&flat, vertices.len(), 16);
        let vertices = meshopt::optimize_vertex_fetch(&mut indices, &vertices);
        // Both codecs only fail for inputs their bounds rule out (sizes
        // checked here): an empty message would then show nothing wrong.
        let v = meshopt::encode_vertex_buffer_level(&vertices, 2, Some(1)).unwrap_or_default();
        let i = meshopt::encode_index_buffer(&indices, vertices.len()).unwrap_or_default();
        (v, i, vertices.len())
    };
    let mut out = Vec::with_capacity(48 + vertex_bytes.len() + index_bytes.len());
    out.extend_from_slice(PART_MAGIC);
    for k in key {
        out.extend_from_slice(&k.to_le_bytes());
    }
    for v in [u32::from(colors), vertex_count as u32, flat.len() as u32] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in origin.to_array() {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&step.to_le_bytes());
    out.extend_from_slice(&(vertex_bytes.len() as u32).to_le_bytes());
    out.extend_from_slice(&vertex_bytes);
    out.extend_from_slice(&index_bytes);
    out
}

/// The message for an image of `kind` (a JPEG).
pub fn encode_image(kind: u32, jpeg: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(8 + jpeg.len());
    out.extend_from_slice(IMAGE_MAGIC);
    out.extend_from_slice(&kind.to_le_bytes());
    out.extend_from_slice(jpeg);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// Decodes a part message: origin, step, and each triangle's corners
    /// in quanta, sorted (the encoder reorders triangles and corners).
    fn decode(message: &[u8]) -> (glam::IVec3, f32, Vec<[[u16; 3]; 3]>) {
        let u32_at = |o: usize| u32::from_le_bytes(message[o..o + 4].try_into().unwrap());
        let f32_at = |o: usize| f32::from_le_bytes(message[o..o + 4].try_into().unwrap());
        assert_eq!(&message[..4], PART_MAGIC);
        let (vertices, indices) = (u32_at(20) as usize, u32_at(24) as usize);
        let split = 48 + u32_at(44) as usize;
        let decoded: Vec<WireVertex> =
            meshopt::decode_vertex_buffer(&message[48..split], vertices).unwrap();
        let index: Vec<u32> = meshopt::decode_index_buffer(&message[split..], indices).unwrap();
        let corner = |i: u32| {
            let p = decoded[i as usize].position;
            [p[0], p[1], p[2]]
        };
        let triangles = index
            .chunks(3)
            .map(|t| sorted([corner(t[0]), corner(t[1]), corner(t[2])]))
            .collect();
        let i32_at = |o: usize| i32::from_le_bytes(message[o..o + 4].try_into().unwrap());
        let origin = glam::IVec3::new(i32_at(28), i32_at(32), i32_at(36));
        (origin, f32_at(40), triangles)
    }

    fn sorted<T: Ord>(mut a: [T; 3]) -> [T; 3] {
        a.sort();
        a
    }

    #[test]
    fn a_part_decodes_to_its_triangles_within_half_a_quantum() {
        let mut mesh = Mesh::default();
        for i in 0..40u32 {
            let a = i as f32 * 0.1;
            mesh.positions.push(Vec3::new(a.cos(), a.sin(), 0.3 * a));
        }
        mesh.triangles = (0..38).map(|i| [i, i + 1, i + 2]).collect();
        let (origin, step, mut got) = decode(&encode_part([1, -2, 3], &mesh));
        assert_eq!(
            step, FINEST_STEP,
            "a part under 32 m across gets the finest step"
        );
        let quantum = |p: Vec3| {
            let q = (p / step).round();
            // Every position is within half a quantum of its grid point.
            assert!((q * step - p).abs().max_element() <= 0.5 * step + 1e-6);
            let q = q.as_ivec3() - origin;
            [q.x as u16, q.y as u16, q.z as u16]
        };
        let mut expected: Vec<[[u16; 3]; 3]> = (0..mesh.triangle_count())
            .map(|t| sorted(mesh.corners(t).map(quantum)))
            .collect();
        got.sort();
        expected.sort();
        assert_eq!(got, expected);
    }

    #[test]
    fn an_empty_part_says_it_is_gone() {
        let message = encode_part([0, 0, 7], &Mesh::default());
        assert_eq!(message.len(), 48);
        assert_eq!(u32::from_le_bytes(message[20..24].try_into().unwrap()), 0);
    }
}
