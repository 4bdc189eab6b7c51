//! Marching cubes over the block map, block by block and incrementally.
//!
//! A block owns the edges that start at its voxels (running +x, +y or +z) and
//! the cubes whose lowest corner is one of its voxels; edges and cubes at its
//! upper faces reach into the neighbouring blocks. Every vertex therefore
//! belongs to exactly one block, and a triangle refers to its vertices by
//! (owning block, edge): assembled, the blocks share their border vertices —
//! no cracks and no duplicates. A block's piece depends only on the voxels of
//! the block and its seven neighbours above (cubes and edges reach one voxel
//! up, normals two; at a block's lower faces normals use one-sided
//! differences rather than reach down), so when a block changes, it and the
//! seven blocks below it are re-meshed and the assembled mesh equals a full
//! extraction.

use super::{cases, voxel_index, KeyMap, TsdfVolume, BLOCK};
use crate::mesh::Mesh;
use glam::{IVec3, Vec3};
use rayon::prelude::*;

/// A reference to a vertex: the owning block as an offset (bit 0: +x, bit 1:
/// +y, bit 2: +z from the referring block) and the edge within it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct EdgeRef {
    owner: u8,
    edge: u16,
}

/// The part of the mesh a block owns.
#[derive(Clone, Debug, Default, PartialEq)]
struct BlockMesh {
    /// Edge ids (voxel index · 3 + axis) of the vertices, ascending.
    edges: Vec<u16>,
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
    /// Vertex colours, when the volume keeps colour.
    colors: Vec<[u8; 3]>,
    triangles: Vec<[EdgeRef; 3]>,
}

/// Per-block mesh pieces, kept up to date with a volume.
#[derive(Debug, Default)]
pub struct MeshCache {
    pieces: KeyMap<BlockMesh>,
    /// Frame of the volume the pieces reflect.
    frame: u32,
    /// Voxels with a smaller weight count as unobserved.
    min_weight: u16,
}

/// Side of the gathered neighbourhood: voxels 0..=9 of a block.
const G: usize = BLOCK + 2;

/// The distances and weights of a block and the first two voxel layers of
/// its neighbours above, so the block can be meshed without further lookups.
struct Neighbourhood {
    tsdf: [f32; G * G * G],
    weight: [u16; G * G * G],
    color: [[u8; 3]; G * G * G],
}

impl Neighbourhood {
    fn gather(volume: &TsdfVolume, key: IVec3) -> Self {
        let mut n = Neighbourhood {
            tsdf: [0.0; G * G * G],
            weight: [0; G * G * G],
            color: [[0; 3]; G * G * G],
        };
        let b = BLOCK as i32;
        for d in 0..8 {
            let offset = IVec3::new(d & 1, (d >> 1) & 1, (d >> 2) & 1);
            let Some(&i) = volume.index().get(&(key + offset)) else {
                continue;
            };
            let block = &volume.blocks()[i as usize];
            // Our own block whole; of a neighbour above, its first two layers.
            let end = |o: i32| if o == 0 { b } else { 2 };
            for z in 0..end(offset.z) {
                for y in 0..end(offset.y) {
                    for x in 0..end(offset.x) {
                        let src = voxel_index(x as usize, y as usize, z as usize);
                        let dst = Self::at(IVec3::new(x, y, z) + offset * b);
                        n.tsdf[dst] = f32::from(block.tsdf[src]) / super::TSDF_SCALE;
                        n.weight[dst] = block.weight[src];
                        if let Some(c) = &block.color {
                            n.color[dst] = c[src];
                        }
                    }
                }
            }
        }
        n
    }

    /// Index of block-local voxel `v` (each coordinate 0..=9).
    #[inline]
    fn at(v: IVec3) -> usize {
        v.x as usize + G * (v.y as usize + G * v.z as usize)
    }

    /// Distance gradient at block-local voxel `v` by central differences,
    /// one-sided where a neighbour was never observed.
    fn gradient(&self, v: IVec3, min_weight: u16) -> Vec3 {
        let mut g = Vec3::ZERO;
        for axis in 0..3 {
            let e = IVec3::AXES[axis];
            let sample = |p: IVec3| {
                if !(p.cmpge(IVec3::ZERO).all() && p.cmplt(IVec3::splat(G as i32)).all()) {
                    return None;
                }
                let i = Self::at(p);
                (self.weight[i] >= min_weight).then(|| self.tsdf[i])
            };
            let c = self.tsdf[Self::at(v)];
            let (lo, hi) = (sample(v - e), sample(v + e));
            g[axis] = match (lo, hi) {
                (Some(l), Some(h)) => 0.5 * (h - l),
                (None, Some(h)) => h - c,
                (Some(l), None) => c - l,
                (None, None) => 0.0,
            };
        }
        g
    }
}

impl MeshCache {
    /// An empty cache; voxels with a weight below `min_weight` (at least 1)
    /// are treated as never observed.
    pub fn new(min_weight: u16) -> Self {
        MeshCache {
            pieces: KeyMap::default(),
            frame: 0,
            min_weight: min_weight.max(1),
        }
    }

    /// Re-meshes the blocks whose input changed since the last update: a
    /// changed block, and those of the seven blocks below it whose border
    /// with it changed; returns how many blocks were meshed.
    pub fn update(&mut self, volume: &TsdfVolume) -> usize {
        let mut dirty: Vec<IVec3> = Vec::new();
        for (block, changes) in volume.blocks().iter().zip(volume.changes()) {
            for d in 0..8 {
                if changes.affecting(d, self.min_weight) > self.frame {
                    let below = block.key
                        - IVec3::new(d as i32 & 1, (d as i32 >> 1) & 1, (d as i32 >> 2) & 1);
                    if volume.index().contains_key(&below) {
                        dirty.push(below);
                    }
                }
            }
        }
        dirty.sort_unstable_by_key(|k| (k.x, k.y, k.z));
        dirty.dedup();
        let min_weight = self.min_weight;
        let pieces: Vec<(IVec3, BlockMesh)> = dirty
            .par_iter()
            .map(|&key| (key, mesh_block(volume, key, min_weight)))
            .collect();
        for (key, piece) in pieces {
            self.pieces.insert(key, piece);
        }
        self.frame = volume.frames();
        dirty.len()
    }

    /// The whole mesh: the blocks' pieces joined, in block-key order.
    pub fn assemble(&self) -> Mesh {
        let keys = sorted_keys(&self.pieces);
        join(&self.pieces, &keys, &keys)
    }

    /// The triangles of the cubes the blocks `keys` own, with only the
    /// vertices they use (some belong to the blocks above).
    pub fn assemble_blocks(&self, keys: &[IVec3]) -> Mesh {
        let mut mesh = join(&self.pieces, &sorted_keys(&self.pieces), keys);
        mesh.remove_unreferenced_vertices();
        mesh
    }

    /// Drops the pieces of blocks that left the volume.
    pub fn forget(&mut self, keys: &[IVec3]) {
        for key in keys {
            self.pieces.remove(key);
        }
    }

    /// Voxels with a smaller weight count as unobserved.
    pub fn min_weight(&self) -> u16 {
        self.min_weight
    }
}

/// The triangles of the cubes the blocks `keys` own, meshed afresh from the
/// volume (with the blocks above them, which own some of their vertices),
/// with only the vertices they use: exactly what a full extraction holds
/// for these blocks.
pub fn extract_blocks(volume: &TsdfVolume, keys: &[IVec3], min_weight: u16) -> Mesh {
    let mut owners: Vec<IVec3> = keys
        .iter()
        .flat_map(|&k| (0..8).map(move |d| k + IVec3::new(d & 1, (d >> 1) & 1, (d >> 2) & 1)))
        .filter(|k| volume.index().contains_key(k))
        .collect();
    owners.sort_unstable_by_key(|k| (k.x, k.y, k.z));
    owners.dedup();
    let pieces: KeyMap<BlockMesh> = owners
        .par_iter()
        .map(|&key| (key, mesh_block(volume, key, min_weight.max(1))))
        .collect();
    let mut mesh = join(&pieces, &owners, keys);
    mesh.remove_unreferenced_vertices();
    mesh
}

fn sorted_keys<V>(map: &KeyMap<V>) -> Vec<IVec3> {
    let mut keys: Vec<IVec3> = map.keys().copied().collect();
    keys.sort_unstable_by_key(|k| (k.x, k.y, k.z));
    keys
}

/// Joins pieces: the vertices of the pieces `vertex_keys` (in that order),
/// and the triangles of the pieces `triangle_keys` whose vertices are among them.
fn join(pieces: &KeyMap<BlockMesh>, vertex_keys: &[IVec3], triangle_keys: &[IVec3]) -> Mesh {
    let mut offsets: KeyMap<u32> = KeyMap::default();
    offsets.reserve(vertex_keys.len());
    let mut mesh = Mesh::default();
    for k in vertex_keys {
        let p = &pieces[k];
        offsets.insert(*k, mesh.positions.len() as u32);
        mesh.positions.extend_from_slice(&p.positions);
        mesh.normals.extend_from_slice(&p.normals);
        mesh.colors.extend_from_slice(&p.colors);
    }
    for k in triangle_keys {
        let Some(p) = pieces.get(k) else {
            continue;
        };
        'triangles: for t in &p.triangles {
            let mut tri = [0u32; 3];
            for (slot, r) in tri.iter_mut().zip(t) {
                let owner = *k
                    + IVec3::new(
                        (r.owner & 1) as i32,
                        ((r.owner >> 1) & 1) as i32,
                        ((r.owner >> 2) & 1) as i32,
                    );
                let (Some(piece), Some(&base)) = (pieces.get(&owner), offsets.get(&owner)) else {
                    continue 'triangles;
                };
                let Ok(local) = piece.edges.binary_search(&r.edge) else {
                    continue 'triangles;
                };
                *slot = base + local as u32;
            }
            mesh.triangles.push(tri);
        }
    }
    mesh
}

/// Whether block `key` may own a vertex or a triangle: an observed voxel of
/// it differs in sign from another observed voxel of it or of the lowest
/// layer of a neighbour above (all that its edges and cubes reach). Most
/// blocks of the truncation band lie wholly in front of or behind the
/// surface; this spares them the gathering.
fn has_surface(volume: &TsdfVolume, key: IVec3, min_weight: u16) -> bool {
    let signs = |block: &super::Block, range: [usize; 3]| {
        let (mut inside, mut outside) = (false, false);
        for z in 0..range[2] {
            for y in 0..range[1] {
                let row = voxel_index(0, y, z);
                for i in row..row + range[0] {
                    let observed = block.weight[i] >= min_weight;
                    inside |= observed & (block.tsdf[i] < 0);
                    outside |= observed & (block.tsdf[i] >= 0);
                }
            }
        }
        (inside, outside)
    };
    let Some(&own) = volume.index().get(&key) else {
        return false;
    };
    let (inside, outside) = signs(&volume.blocks()[own as usize], [BLOCK; 3]);
    if inside && outside {
        return true;
    }
    if !(inside || outside) {
        // Every edge and cube starts at an observed voxel of the block.
        return false;
    }
    (1..8).any(|d| {
        let offset = IVec3::new(d & 1, (d >> 1) & 1, (d >> 2) & 1);
        volume.index().get(&(key + offset)).is_some_and(|&i| {
            let range = offset.to_array().map(|o| if o == 0 { BLOCK } else { 1 });
            let (i_in, i_out) = signs(&volume.blocks()[i as usize], range);
            (inside && i_out) || (outside && i_in)
        })
    })
}

/// Steps between neighbouring voxels of a gathered neighbourhood, per axis.
const STEP: [usize; 3] = [1, G, G * G];

/// Meshes the edges and cubes block `key` owns.
fn mesh_block(volume: &TsdfVolume, key: IVec3, min_weight: u16) -> BlockMesh {
    let mut out = BlockMesh::default();
    if !has_surface(volume, key, min_weight) {
        return out;
    }
    let n = Neighbourhood::gather(volume, key);
    // Per gathered voxel: bit 0 observed, bit 1 inside (negative).
    let state: Vec<u8> = n
        .tsdf
        .iter()
        .zip(&n.weight)
        .map(|(&t, &w)| u8::from(w >= min_weight) | u8::from(t < 0.0) << 1)
        .collect();
    let b = BLOCK as i32;
    let voxel = volume.config().voxel;
    let origin = volume.voxel_position(key, 0, 0, 0);
    // Vertices on the owned edges, in edge-id order.
    for z in 0..b {
        for y in 0..b {
            for x in 0..b {
                let v = IVec3::new(x, y, z);
                let i = Neighbourhood::at(v);
                if state[i] & 1 == 0 {
                    continue;
                }
                for (axis, step) in STEP.iter().enumerate() {
                    let j = i + step;
                    if state[j] & 1 == 0 || (state[i] ^ state[j]) & 2 == 0 {
                        continue;
                    }
                    let (f0, f1) = (n.tsdf[i], n.tsdf[j]);
                    let t = f0 / (f0 - f1);
                    let w = v + IVec3::AXES[axis];
                    out.edges
                        .push((voxel_index(x as usize, y as usize, z as usize) * 3 + axis) as u16);
                    out.positions.push(
                        origin + v.as_vec3() * voxel + IVec3::AXES[axis].as_vec3() * (t * voxel),
                    );
                    let g = n.gradient(v, min_weight).lerp(n.gradient(w, min_weight), t);
                    out.normals.push(g.normalize_or_zero());
                    if volume.config().color {
                        let (c0, c1) = (n.color[i], n.color[j]);
                        out.colors.push(std::array::from_fn(|ch| {
                            (f32::from(c0[ch]) + (f32::from(c1[ch]) - f32::from(c0[ch])) * t + 0.5)
                                as u8
                        }));
                    }
                }
            }
        }
    }
    // Triangles of the owned cubes.
    let table = cases::table();
    let corner_step =
        cases::CORNERS.map(|c| c[0] as usize + G * (c[1] as usize + G * c[2] as usize));
    for z in 0..b {
        for y in 0..b {
            for x in 0..b {
                let base = IVec3::new(x, y, z);
                let i = Neighbourhood::at(base);
                let (mut case, mut observed) = (0usize, 1u8);
                for (c, step) in corner_step.iter().enumerate() {
                    let s = state[i + step];
                    observed &= s;
                    case |= usize::from(s >> 1) << c;
                }
                if observed == 0 {
                    continue;
                }
                for tri in &table[case] {
                    out.triangles.push(tri.map(|e| {
                        let (a, bb) = cases::EDGES[e as usize];
                        let c = cases::CORNERS[a as usize];
                        let start = base + IVec3::new(c[0] as i32, c[1] as i32, c[2] as i32);
                        let d = cases::CORNERS[bb as usize];
                        let axis = (0..3)
                            .find(|&k| d[k] != c[k])
                            .expect("an edge runs along one axis");
                        let owner = IVec3::new(
                            (start.x >= b) as i32,
                            (start.y >= b) as i32,
                            (start.z >= b) as i32,
                        );
                        let local = start - owner * b;
                        EdgeRef {
                            owner: (owner.x | owner.y << 1 | owner.z << 2) as u8,
                            edge: (voxel_index(
                                local.x as usize,
                                local.y as usize,
                                local.z as usize,
                            ) * 3
                                + axis) as u16,
                        }
                    }));
                }
            }
        }
    }
    out
}
