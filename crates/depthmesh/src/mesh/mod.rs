//! Triangle meshes and their files.

pub mod align;
pub mod chunk;
pub mod chunk_files;
pub mod glb;
pub mod io;
pub mod obj;
pub mod ply;
pub mod simplify;
pub mod weld;

use glam::Vec3;

/// An indexed triangle mesh. `normals` and `colors` are either empty or have
/// one entry per vertex.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions in metres.
    pub positions: Vec<Vec3>,
    /// Per-vertex unit normals, or empty.
    pub normals: Vec<Vec3>,
    /// Per-vertex RGB colours, or empty.
    pub colors: Vec<[u8; 3]>,
    /// Triangles as counter-clockwise vertex index triples.
    pub triangles: Vec<[u32; 3]>,
}

/// The run `run` of a per-vertex attribute, or nothing when it is absent.
fn run_of<T: Copy>(attribute: &[T], run: &std::ops::Range<usize>) -> Vec<T> {
    if attribute.is_empty() {
        Vec::new()
    } else {
        attribute[run.clone()].to_vec()
    }
}

/// An axis-aligned bounding box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Smallest corner.
    pub min: Vec3,
    /// Largest corner.
    pub max: Vec3,
}

impl Aabb {
    /// The empty box (contains nothing; grows with [`Aabb::include`]).
    pub const EMPTY: Aabb = Aabb {
        min: Vec3::splat(f32::INFINITY),
        max: Vec3::splat(f32::NEG_INFINITY),
    };

    /// Grows the box to contain `p`.
    pub fn include(&mut self, p: Vec3) {
        self.min = self.min.min(p);
        self.max = self.max.max(p);
    }

    /// Whether nothing was included.
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x
    }

    /// Size along each axis.
    pub fn extent(&self) -> Vec3 {
        self.max - self.min
    }

    /// Centre point.
    pub fn center(&self) -> Vec3 {
        0.5 * (self.min + self.max)
    }
}

impl Mesh {
    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.positions.len()
    }

    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Whether the mesh has no triangles.
    pub fn is_empty(&self) -> bool {
        self.triangles.is_empty()
    }

    /// The bounding box of all vertices.
    pub fn bounds(&self) -> Aabb {
        let mut b = Aabb::EMPTY;
        for &p in &self.positions {
            b.include(p);
        }
        b
    }

    /// Corner positions of triangle `t`.
    #[inline]
    pub fn corners(&self, t: usize) -> [Vec3; 3] {
        let [a, b, c] = self.triangles[t];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }

    /// Area of triangle `t` in square metres.
    pub fn triangle_area(&self, t: usize) -> f32 {
        let [a, b, c] = self.corners(t);
        0.5 * (b - a).cross(c - a).length()
    }

    /// Total surface area in square metres.
    pub fn area(&self) -> f64 {
        (0..self.triangles.len())
            .map(|t| self.triangle_area(t) as f64)
            .sum()
    }

    /// Each triangle as its corners' exact (position, normal) bits, starting
    /// at the smallest corner (winding kept), appended to `set`: sorted, the
    /// triangles of one or more meshes up to vertex and triangle order, to
    /// compare maps made in pieces with maps made whole.
    pub fn triangle_records(&self, set: &mut Vec<[[u32; 6]; 3]>) {
        let normal = |i: usize| self.normals.get(i).copied().unwrap_or(Vec3::ZERO);
        for t in &self.triangles {
            let corner = |i: u32| {
                let (p, n) = (self.positions[i as usize], normal(i as usize));
                [p.x, p.y, p.z, n.x, n.y, n.z].map(f32::to_bits)
            };
            let mut c = t.map(corner);
            let first = (0..3).min_by_key(|&i| c[i]).expect("three corners");
            c.rotate_left(first);
            set.push(c);
        }
    }

    /// Appends `other`, re-indexing its triangles. Attributes present on only
    /// one side are dropped, since they would not cover every vertex.
    pub fn append(&mut self, other: &Mesh) {
        let base = self.positions.len() as u32;
        let keep_normals = self.normals.len() == self.positions.len()
            && other.normals.len() == other.positions.len()
            && (!self.normals.is_empty() || self.positions.is_empty());
        let keep_colors = self.colors.len() == self.positions.len()
            && other.colors.len() == other.positions.len()
            && (!self.colors.is_empty() || self.positions.is_empty());
        self.positions.extend_from_slice(&other.positions);
        if keep_normals {
            self.normals.extend_from_slice(&other.normals);
        } else {
            self.normals.clear();
        }
        if keep_colors {
            self.colors.extend_from_slice(&other.colors);
        } else {
            self.colors.clear();
        }
        self.triangles.extend(
            other
                .triangles
                .iter()
                .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
        );
    }

    /// The triangles `range` as a mesh of their own, with only the vertices
    /// they use. Cheap when they use a short run of vertices, as a patch of
    /// a mesh grown by appending does.
    pub fn triangle_range(&self, range: std::ops::Range<usize>) -> Mesh {
        let triangles = &self.triangles[range];
        let Some((lo, hi)) =
            triangles
                .iter()
                .flatten()
                .fold(None, |acc: Option<(u32, u32)>, &v| {
                    Some(acc.map_or((v, v + 1), |(lo, hi)| (lo.min(v), hi.max(v + 1))))
                })
        else {
            return Mesh::default();
        };
        let run = lo as usize..hi as usize;
        let mut mesh = Mesh {
            positions: self.positions[run.clone()].to_vec(),
            normals: run_of(&self.normals, &run),
            colors: run_of(&self.colors, &run),
            triangles: triangles.iter().map(|t| t.map(|v| v - lo)).collect(),
        };
        mesh.remove_unreferenced_vertices();
        mesh
    }

    /// Applies `f` to every position and `g` to every normal.
    pub fn transform(&mut self, f: impl Fn(Vec3) -> Vec3, g: impl Fn(Vec3) -> Vec3) {
        for p in &mut self.positions {
            *p = f(*p);
        }
        for n in &mut self.normals {
            *n = g(*n).normalize_or_zero();
        }
    }

    /// Area-weighted vertex normals from the triangles.
    pub fn compute_vertex_normals(&mut self) {
        let mut normals = vec![Vec3::ZERO; self.positions.len()];
        for t in 0..self.triangles.len() {
            let [a, b, c] = self.corners(t);
            let n = (b - a).cross(c - a);
            for &i in &self.triangles[t] {
                normals[i as usize] += n;
            }
        }
        for n in &mut normals {
            *n = n.normalize_or_zero();
        }
        self.normals = normals;
    }

    /// Drops vertices no triangle uses, keeping the order of the others.
    pub fn remove_unreferenced_vertices(&mut self) {
        let mut remap = vec![u32::MAX; self.positions.len()];
        for t in &self.triangles {
            for &i in t {
                remap[i as usize] = 0;
            }
        }
        let mut next = 0u32;
        for r in &mut remap {
            if *r == 0 {
                *r = next;
                next += 1;
            }
        }
        if next as usize == self.positions.len() {
            return;
        }
        let keep = |i: usize| remap[i] != u32::MAX;
        let mut i = 0;
        self.positions.retain(|_| {
            i += 1;
            keep(i - 1)
        });
        if !self.normals.is_empty() {
            let mut i = 0;
            self.normals.retain(|_| {
                i += 1;
                keep(i - 1)
            });
        }
        if !self.colors.is_empty() {
            let mut i = 0;
            self.colors.retain(|_| {
                i += 1;
                keep(i - 1)
            });
        }
        for t in &mut self.triangles {
            for i in t {
                *i = remap[*i as usize];
            }
        }
    }

    /// Checks that every index is in range and attribute arrays have the right length.
    pub fn check(&self) -> Result<(), String> {
        let n = self.positions.len();
        if !self.normals.is_empty() && self.normals.len() != n {
            return Err(format!("{} normals for {} vertices", self.normals.len(), n));
        }
        if !self.colors.is_empty() && self.colors.len() != n {
            return Err(format!("{} colours for {} vertices", self.colors.len(), n));
        }
        if let Some((t, tri)) = self
            .triangles
            .iter()
            .enumerate()
            .find(|(_, tri)| tri.iter().any(|&i| i as usize >= n))
        {
            return Err(format!(
                "face {t} uses vertex {:?} but there are only {n} vertices",
                tri
            ));
        }
        Ok(())
    }
}

/// Copies of `clean` with four bytes overwritten at random (xorshift from
/// `seed`), for checking that readers fail cleanly on corrupted files.
#[cfg(test)]
pub(crate) fn corrupted_copies(
    clean: &[u8],
    seed: u64,
    copies: usize,
) -> impl Iterator<Item = Vec<u8>> + '_ {
    let mut state = seed;
    (0..copies).map(move |_| {
        let mut bytes = clean.to_vec();
        for _ in 0..4 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let at = (state >> 8) as usize % bytes.len();
            bytes[at] = state as u8;
        }
        bytes
    })
}
