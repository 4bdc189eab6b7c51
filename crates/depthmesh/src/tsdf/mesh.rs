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
//! differences rather than reach down), so a block is re-meshed when its own
//! voxels or the lowest two layers of a neighbour above changed as the mesh
//! sees them (see [`super::changes`]), and the assembled mesh equals a full
//! extraction. Blocks without a sign change are skipped before gathering,
//! and sign changes are found a bit row at a time.

use super::{cases, voxel_index, KeyMap, TsdfVolume, ABOVE, BLOCK};
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

/// The distances (stored units) and observed/inside states of a block and
/// the first two voxel layers of its neighbours above, so the block can be
/// meshed without further lookups. Unscaled distances are fine: vertices
/// interpolate ratios of them and normals are normalised.
struct Neighbourhood {
    tsdf: [i16; G * G * G],
    /// Bit 0: observed (weight ≥ the minimum); bit 1: inside (negative).
    state: [u8; G * G * G],
    /// Colours, when the volume keeps them.
    color: Option<Box<[[u8; 3]; G * G * G]>>,
}

impl Neighbourhood {
    fn gather(volume: &TsdfVolume, key: IVec3, min_weight: u16) -> Self {
        let mut n = Neighbourhood {
            tsdf: [0; G * G * G],
            state: [0; G * G * G],
            color: volume.config().color.then(|| Box::new([[0; 3]; G * G * G])),
        };
        for d in 0..8 {
            let offset = IVec3::new(d & 1, (d >> 1) & 1, (d >> 2) & 1);
            let Some(&i) = volume.index().get(&(key + offset)) else {
                continue;
            };
            let block = &volume.blocks()[i as usize];
            // Our own block whole; of a neighbour above, its first two layers.
            let end = offset.to_array().map(|o| if o == 0 { BLOCK } else { 2 });
            let start = Self::at(offset * BLOCK as i32);
            for z in 0..end[2] {
                for y in 0..end[1] {
                    let (src, dst) = (voxel_index(0, y, z), start + y * G + z * G * G);
                    // Rows of a length known when compiling copy without a call.
                    if end[0] == BLOCK {
                        n.copy_row::<BLOCK>(block, src, dst, min_weight);
                    } else {
                        n.copy_row::<2>(block, src, dst, min_weight);
                    }
                }
            }
        }
        n
    }

    /// Copies `LEN` voxels from `block` (from voxel `src`) to gathered voxel `dst` on.
    #[inline(always)]
    fn copy_row<const LEN: usize>(
        &mut self,
        block: &super::Block,
        src: usize,
        dst: usize,
        min_weight: u16,
    ) {
        let tsdf: &[i16; LEN] = block.tsdf[src..src + LEN].try_into().expect("LEN voxels");
        let weight: &[u16; LEN] = block.weight[src..src + LEN].try_into().expect("LEN voxels");
        self.tsdf[dst..dst + LEN].copy_from_slice(tsdf);
        for ((s, &w), &t) in self.state[dst..dst + LEN].iter_mut().zip(weight).zip(tsdf) {
            *s = u8::from(w >= min_weight) | u8::from(t < 0) << 1;
        }
        if let (Some(to), Some(from)) = (self.color.as_deref_mut(), &block.color) {
            to[dst..dst + LEN].copy_from_slice(&from[src..src + LEN]);
        }
    }

    /// Index of block-local voxel `v` (each coordinate 0..=9).
    #[inline]
    fn at(v: IVec3) -> usize {
        v.x as usize + G * (v.y as usize + G * v.z as usize)
    }

    /// Distance gradient at block-local voxel `v` by central differences,
    /// one-sided where a neighbour was never observed.
    fn gradient(&self, v: IVec3) -> Vec3 {
        let i = Self::at(v);
        let sample = |j: usize| (self.state[j] & 1 != 0).then(|| f32::from(self.tsdf[j]));
        let c = f32::from(self.tsdf[i]);
        let mut g = Vec3::ZERO;
        for (axis, step) in STEP.iter().enumerate() {
            let lo = (v[axis] > 0).then(|| sample(i - step)).flatten();
            let hi = ((v[axis] as usize) < G - 1)
                .then(|| sample(i + step))
                .flatten();
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
        let dirty = changed_since(volume, self.frame, self.min_weight);
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

/// The blocks whose piece of the mesh may differ from what it was after
/// frame `since` (see [`MeshCache::update`]): a changed block, and those of
/// the seven blocks below it whose border with it changed; sorted.
pub fn changed_since(volume: &TsdfVolume, since: u32, min_weight: u16) -> Vec<IVec3> {
    let mut dirty: Vec<IVec3> = Vec::new();
    for (block, changes) in volume.blocks().iter().zip(volume.changes()) {
        for d in 0..8 {
            if changes.affecting(d, min_weight.max(1)) > since {
                let below =
                    block.key - IVec3::new(d as i32 & 1, (d as i32 >> 1) & 1, (d as i32 >> 2) & 1);
                if volume.index().contains_key(&below) {
                    dirty.push(below);
                }
            }
        }
    }
    dirty.sort_unstable_by_key(|k| (k.x, k.y, k.z));
    dirty.dedup();
    dirty
}

/// The triangles of the cubes the blocks `keys` own, meshed afresh from the
/// volume (with the blocks above them, which own some of their vertices),
/// with only the vertices they use: exactly what a full extraction holds
/// for these blocks.
pub fn extract_blocks(volume: &TsdfVolume, keys: &[IVec3], min_weight: u16) -> Mesh {
    let (pieces, owners) = mesh_owners(volume, keys, min_weight);
    let mut mesh = join(&pieces, &owners, keys);
    mesh.remove_unreferenced_vertices();
    mesh
}

/// Like [`extract_blocks`] for each set of blocks in `sets`, meshing every
/// block once however many sets need it (neighbouring sets share the blocks
/// above their borders).
pub fn extract_sets(volume: &TsdfVolume, sets: &[Vec<IVec3>], min_weight: u16) -> Vec<Mesh> {
    let all: Vec<IVec3> = sets.iter().flatten().copied().collect();
    let (pieces, _) = mesh_owners(volume, &all, min_weight);
    sets.par_iter()
        .map(|keys| {
            let owners = owners_of(keys, |k| pieces.contains_key(k));
            let mut mesh = join(&pieces, &owners, keys);
            mesh.remove_unreferenced_vertices();
            mesh
        })
        .collect()
}

/// Meshes the blocks `keys` and those above them that own vertices of
/// theirs; the pieces, and the owners in key order.
fn mesh_owners(
    volume: &TsdfVolume,
    keys: &[IVec3],
    min_weight: u16,
) -> (KeyMap<BlockMesh>, Vec<IVec3>) {
    let owners = owners_of(keys, |k| volume.index().contains_key(k));
    let pieces: KeyMap<BlockMesh> = owners
        .par_iter()
        .map(|&key| (key, mesh_block(volume, key, min_weight.max(1))))
        .collect();
    (pieces, owners)
}

/// The blocks that own vertices of the blocks `keys` (each, and its seven
/// neighbours above) among those `held`, in key order.
fn owners_of(keys: &[IVec3], held: impl Fn(&IVec3) -> bool) -> Vec<IVec3> {
    let mut owners: Vec<IVec3> = keys
        .iter()
        .flat_map(|&k| ABOVE.map(|o| k + o))
        .filter(|k| held(k))
        .collect();
    owners.sort_unstable_by_key(|k| (k.x, k.y, k.z));
    owners.dedup();
    owners
}

fn sorted_keys<V>(map: &KeyMap<V>) -> Vec<IVec3> {
    let mut keys: Vec<IVec3> = map.keys().copied().collect();
    keys.sort_unstable_by_key(|k| (k.x, k.y, k.z));
    keys
}

/// Joins pieces: the vertices of the pieces `vertex_keys` (in that order),
/// and the triangles of the pieces `triangle_keys` whose vertices are among them.
fn join(pieces: &KeyMap<BlockMesh>, vertex_keys: &[IVec3], triangle_keys: &[IVec3]) -> Mesh {
    let mut offsets: KeyMap<(u32, &BlockMesh)> = KeyMap::default();
    offsets.reserve(vertex_keys.len());
    let mut mesh = Mesh::default();
    for k in vertex_keys {
        let p = &pieces[k];
        offsets.insert(*k, (mesh.positions.len() as u32, p));
        mesh.positions.extend_from_slice(&p.positions);
        mesh.normals.extend_from_slice(&p.normals);
        mesh.colors.extend_from_slice(&p.colors);
    }
    // Block by block in parallel: the eight possible owners are looked up
    // once per block, not once per corner.
    let triangles: Vec<Vec<[u32; 3]>> = triangle_keys
        .par_iter()
        .map(|k| {
            let Some(p) = pieces.get(k) else {
                return Vec::new();
            };
            let owners: [Option<&(u32, &BlockMesh)>; 8] = std::array::from_fn(|d| {
                let d = d as i32;
                offsets.get(&(*k + IVec3::new(d & 1, (d >> 1) & 1, (d >> 2) & 1)))
            });
            let resolve = |r: &EdgeRef| {
                let (base, piece) = owners[r.owner as usize]?;
                let local = piece.edges.binary_search(&r.edge).ok()?;
                Some(base + local as u32)
            };
            p.triangles
                .iter()
                .filter_map(|t| Some([resolve(&t[0])?, resolve(&t[1])?, resolve(&t[2])?]))
                .collect()
        })
        .collect();
    mesh.triangles = triangles.concat();
    mesh
}

/// Whether block `key` may own a vertex or a triangle: an observed voxel of
/// it differs in sign from another observed voxel of it or of the lowest
/// layer of a neighbour above (all that its edges and cubes reach). Most
/// blocks of the truncation band lie wholly in front of or behind the
/// surface; this spares them the gathering.
fn has_surface(volume: &TsdfVolume, key: IVec3, min_weight: u16) -> bool {
    // Whether observed voxels among these lie inside, and outside.
    let scan = |tsdf: &[i16], weight: &[u16]| {
        tsdf.iter()
            .zip(weight)
            .fold((false, false), |(inside, outside), (&t, &w)| {
                let observed = w >= min_weight;
                (
                    inside | (observed & (t < 0)),
                    outside | (observed & (t >= 0)),
                )
            })
    };
    let signs = |block: &super::Block, range: [usize; 3]| {
        let (mut inside, mut outside) = (false, false);
        for z in 0..range[2] {
            for y in 0..range[1] {
                let row = voxel_index(0, y, z)..voxel_index(range[0], y, z);
                let (i, o) = scan(&block.tsdf[row.clone()], &block.weight[row]);
                (inside, outside) = (inside | i, outside | o);
            }
        }
        (inside, outside)
    };
    let Some(&own) = volume.index().get(&key) else {
        return false;
    };
    // The whole block at once: one long loop the compiler vectorises.
    let block = &volume.blocks()[own as usize];
    let (inside, outside) = scan(&block.tsdf[..], &block.weight[..]);
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
    let n = Neighbourhood::gather(volume, key, min_weight);
    let state = &n.state;
    // Bit rows along x (bit x = voxel x) of the observed and the inside
    // voxels, per (y, z): sign changes are found a row at a time, and only
    // the few edges and cubes the surface crosses are visited.
    let mut observed = [[0u16; G]; G];
    let mut inside = [[0u16; G]; G];
    for z in 0..G {
        for y in 0..G {
            let row = &state[Neighbourhood::at(IVec3::new(0, y as i32, z as i32))..][..G];
            for (x, &s) in row.iter().enumerate() {
                observed[z][y] |= u16::from(s & 1) << x;
                inside[z][y] |= u16::from(s >> 1) << x;
            }
        }
    }
    let b = BLOCK as i32;
    let voxel = volume.config().voxel;
    let origin = volume.voxel_position(key, 0, 0, 0);
    let own = (1u16 << BLOCK) - 1;
    // Per row of voxels, the edges the surface crosses (per axis) and the
    // cubes it passes through — all corners observed, not all on one side —
    // counted first so the piece's arrays are allocated once.
    let mut crossings = [[[0u16; 3]; BLOCK]; BLOCK];
    let mut cube_rows = [[0u16; BLOCK]; BLOCK];
    let (mut vertices, mut cubes) = (0, 0);
    for z in 0..BLOCK {
        for y in 0..BLOCK {
            let (o, i) = (observed[z][y], inside[z][y]);
            crossings[z][y] = [
                o & (o >> 1) & (i ^ (i >> 1)),
                o & observed[z][y + 1] & (i ^ inside[z][y + 1]),
                o & observed[z + 1][y] & (i ^ inside[z + 1][y]),
            ]
            .map(|m| m & own);
            let rows = [(z, y), (z, y + 1), (z + 1, y), (z + 1, y + 1)];
            let (mut all_observed, mut any_inside, mut all_inside) = (own, 0u16, own);
            for (rz, ry) in rows {
                let (o, i) = (observed[rz][ry], inside[rz][ry]);
                all_observed &= o & (o >> 1);
                any_inside |= i | (i >> 1);
                all_inside &= i & (i >> 1);
            }
            cube_rows[z][y] = all_observed & any_inside & !all_inside;
            vertices += crossings[z][y].map(u16::count_ones).iter().sum::<u32>() as usize;
            cubes += cube_rows[z][y].count_ones() as usize;
        }
    }
    out.edges.reserve_exact(vertices);
    out.positions.reserve_exact(vertices);
    out.normals.reserve_exact(vertices);
    if n.color.is_some() {
        out.colors.reserve_exact(vertices);
    }
    // Most crossed cubes hold one or two triangles.
    out.triangles.reserve(2 * cubes);
    // Vertices on the owned edges, in edge-id order (voxel, then axis).
    for (z, plane) in crossings.iter().enumerate() {
        for (y, &crossing) in plane.iter().enumerate() {
            let mut any = crossing[0] | crossing[1] | crossing[2];
            while any != 0 {
                let x = any.trailing_zeros() as usize;
                any &= any - 1;
                let v = IVec3::new(x as i32, y as i32, z as i32);
                let i = Neighbourhood::at(v);
                for (axis, step) in STEP.iter().enumerate() {
                    if crossing[axis] & (1 << x) == 0 {
                        continue;
                    }
                    let j = i + step;
                    let (f0, f1) = (f32::from(n.tsdf[i]), f32::from(n.tsdf[j]));
                    let t = f0 / (f0 - f1);
                    let w = v + IVec3::AXES[axis];
                    out.edges.push((voxel_index(x, y, z) * 3 + axis) as u16);
                    out.positions.push(
                        origin + v.as_vec3() * voxel + IVec3::AXES[axis].as_vec3() * (t * voxel),
                    );
                    let g = n.gradient(v).lerp(n.gradient(w), t);
                    out.normals.push(g.normalize_or_zero());
                    if let Some(color) = n.color.as_deref() {
                        let (c0, c1) = (color[i], color[j]);
                        out.colors.push(std::array::from_fn(|ch| {
                            (f32::from(c0[ch]) + (f32::from(c1[ch]) - f32::from(c0[ch])) * t + 0.5)
                                as u8
                        }));
                    }
                }
            }
        }
    }
    // Triangles of the owned cubes; per cube edge, its start corner and axis.
    let table = cases::table();
    let edge_start = cases::EDGES.map(|(a, bb)| {
        let (c, d) = (cases::CORNERS[a as usize], cases::CORNERS[bb as usize]);
        let axis = (0..3)
            .find(|&k| d[k] != c[k])
            .expect("an edge runs along one axis");
        (IVec3::new(c[0] as i32, c[1] as i32, c[2] as i32), axis)
    });
    let corner_step =
        cases::CORNERS.map(|c| c[0] as usize + G * (c[1] as usize + G * c[2] as usize));
    let edge_ref = |base: IVec3, e: u8| {
        let (corner, axis) = edge_start[e as usize];
        let start = base + corner;
        let owner = start.cmpge(IVec3::splat(b));
        let local = start - IVec3::select(owner, IVec3::splat(b), IVec3::ZERO);
        EdgeRef {
            owner: owner.bitmask() as u8,
            edge: (voxel_index(local.x as usize, local.y as usize, local.z as usize) * 3 + axis)
                as u16,
        }
    };
    for (z, plane) in cube_rows.iter().enumerate() {
        for (y, &row) in plane.iter().enumerate() {
            let mut cubes = row;
            while cubes != 0 {
                let x = cubes.trailing_zeros() as usize;
                cubes &= cubes - 1;
                let base = IVec3::new(x as i32, y as i32, z as i32);
                let i = Neighbourhood::at(base);
                let mut case = 0usize;
                for (c, step) in corner_step.iter().enumerate() {
                    case |= usize::from(state[i + step] >> 1) << c;
                }
                for tri in &table[case] {
                    out.triangles.push([
                        edge_ref(base, tri[0]),
                        edge_ref(base, tri[1]),
                        edge_ref(base, tri[2]),
                    ]);
                }
            }
        }
    }
    out
}
