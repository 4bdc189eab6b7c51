//! Online simplification of settled surface: M stays small as a run goes on.
//!
//! M grows by *patches*: the novel surface of one iteration. With settling
//! on, a patch is meshed adaptively from the start
//! ([`DepthMesher::mesh_adaptive`](crate::mabdi::mesher::DepthMesher::mesh_adaptive)):
//! large triangles where they keep every pixel within about `error · τ(z)`
//! at its own depth, pixel-size ones elsewhere, which cuts what E renders
//! and what settling simplifies several-fold (noisy dynamic bunnies: final
//! M 197,424 → 170,181 triangles, the mean iteration 17 → 13 ms). A patch is **settled** once `after` iterations
//! have passed since it was added or last changed. Settled patches are simplified once, by
//! quadric edge collapse (meshoptimizer, [`crate::mesh::simplify`]), in
//! groups of consecutive triangles (a few of the mesher's pixel tiles, so a
//! group spans a small range of depths), each to a geometric error of
//! `error · τ(z)`, with `τ` the novelty threshold and `z` the group's nearest
//! depth from the pose that saw it. With the default `error` of 0.2 that is
//! σ of the thesis's noise, a fifth of what classification tolerates (with
//! the adaptive mesher's error before it, surface moves by at most about
//! two fifths): E, the classification and the removal evidence are unchanged
//! in effect (the novel pixels per frame stay within 0.1 % of a frame),
//! while a flat floor tile of 8,192 triangles becomes a few hundred.
//!
//! The seams between a patch's groups are locked, so groups still meet
//! exactly. The patch's outline (and the holes in it) is simplified along
//! itself, within the same error: meshoptimizer moves a border vertex only
//! along the border. Patches share no vertices, and most of a noisy
//! patch's triangles touch its ragged outline, so with the outline locked
//! as well M kept a triangle for nearly every border edge (300,000 border
//! edges for 470,000 triangles on the noisy bunnies). Kept vertices keep their colour (the iteration that
//! added them). Triangles holding removal votes are kept as they are, with
//! their votes; the new triangles start with none. A patch counts as
//! changed when it loses 1 % of its triangles in one iteration (noise
//! takes a spike now and then; a patch losing a real part of itself is
//! changing). Patches that came with a starting mesh are left alone:
//! the pose that saw them is not known.

use crate::camera::Pose;
use crate::error::Result;
use crate::mabdi::classify::Threshold;
use crate::mesh::simplify::{simplify_locked, SimplifyParams};
use crate::mesh::Mesh;
use crate::raster::is_hole;
use rayon::prelude::*;
use std::collections::HashMap;

/// Parameters of the simplification of settled surface.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Settling {
    /// Iterations a patch must go unchanged before it is simplified.
    pub after: u32,
    /// Largest geometric error, as a fraction of the novelty threshold τ(z).
    pub error: f32,
}

impl Settling {
    /// The adaptive mesher's bound, `(a, b)` in metres `a + b·z²` at depth
    /// z: the same fraction `error` of the novelty threshold as settling's own.
    pub fn mesher_bound(&self, novelty: Threshold) -> (f32, f32) {
        let (a, b) = novelty.quadratic();
        (self.error * a, self.error * b)
    }
}

/// Triangles per simplification group at most: two of the mesher's
/// 64×64-pixel tiles.
const GROUP: usize = 2 * 64 * 64 * 2;
/// Triangles per simplification group at least (unless the patch is smaller):
/// a quarter of a tile, so that seams stay a small part of a group.
const MIN_GROUP: usize = 64 * 64 / 2;

/// Triangles per simplification group for a patch of `triangles`: at least
/// two groups where it has room for them, so that a patch settles on two
/// cores (one iteration's patch is often smaller than one group), and the
/// same split however many threads run, so M does not depend on them.
fn group_size(triangles: usize) -> usize {
    triangles.div_ceil(2).clamp(MIN_GROUP, GROUP)
}

/// One iteration's addition to M.
#[derive(Clone, Copy, Debug)]
struct Patch {
    /// Its name for viewers: patches are numbered as they come.
    id: u32,
    /// Triangles it has now.
    len: usize,
    /// Slots of M it spans: its triangles and the holes removal left among
    /// them (see [`crate::raster::is_hole`]) until M is closed up.
    slots: usize,
    /// The sensor pose that saw it, if known.
    pose: Option<Pose>,
    /// Last iteration at which it was added to or lost triangles.
    changed: u32,
    /// Whether it has been simplified (or is never to be).
    done: bool,
}

/// The patches of M, in M's triangle order (which is also their ids' order).
#[derive(Clone, Debug, Default)]
pub struct Patches {
    patches: Vec<Patch>,
    /// The id the next patch gets.
    next_id: u32,
    /// Patches added, changed or emptied since [`Patches::take_changed`],
    /// while a viewer follows M.
    changed: Option<Vec<u32>>,
}

/// A patch as saved: id, triangles, the iteration it last changed at,
/// whether it is done, and the pose that saw it (rotation columns, then
/// translation) if known.
pub type SavedPatch = (u32, usize, u32, bool, Option<[f32; 12]>);

impl Patches {
    /// The patches and the next patch's id, to save (from a closed-up M,
    /// whose patches span no holes).
    pub fn saved(&self) -> (Vec<SavedPatch>, u32) {
        let patches = self
            .patches
            .iter()
            .map(|p| {
                let pose = p.pose.map(|pose| {
                    let mut a = [0.0; 12];
                    a[..9].copy_from_slice(&pose.rotation.to_cols_array());
                    a[9..].copy_from_slice(&pose.translation.to_array());
                    a
                });
                (p.id, p.len, p.changed, p.done, pose)
            })
            .collect();
        (patches, self.next_id)
    }

    /// Patches as [`Patches::saved`] gave them.
    pub fn restore(patches: &[SavedPatch], next_id: u32) -> Self {
        let patches = patches
            .iter()
            .map(|&(id, len, changed, done, pose)| Patch {
                id,
                len,
                slots: len,
                pose: pose.map(|a| {
                    Pose::new(
                        glam::Mat3::from_cols_slice(&a[..9]),
                        glam::Vec3::new(a[9], a[10], a[11]),
                    )
                }),
                changed,
                done,
            })
            .collect();
        Patches {
            patches,
            next_id,
            changed: None,
        }
    }

    /// Slots of M the patches span (M's triangle count, holes included).
    pub fn slots(&self) -> usize {
        self.patches.iter().map(|p| p.slots).sum()
    }

    /// Triangles the patches hold (holes not counted).
    pub fn triangles(&self) -> usize {
        self.patches.iter().map(|p| p.len).sum()
    }

    /// The first slot of each patch.
    fn starts(&self) -> Vec<usize> {
        let mut start = 0;
        self.patches
            .iter()
            .map(|p| {
                start += p.slots;
                start - p.slots
            })
            .collect()
    }

    /// Numbers a new patch and notes it for viewers.
    fn new_id(&mut self) -> u32 {
        let id = self.next_id;
        self.next_id += 1;
        self.note(id);
        id
    }

    fn note(&mut self, id: u32) {
        if let Some(changed) = &mut self.changed {
            changed.push(id);
        }
    }

    /// Starts noting changed patches for a viewer; returns every patch's id.
    pub fn follow(&mut self) -> Vec<u32> {
        self.changed = Some(Vec::new());
        self.patches.iter().map(|p| p.id).collect()
    }

    /// The patches added, changed or emptied since the last call (or
    /// [`Patches::follow`]), ascending; empty when not followed.
    pub fn take_changed(&mut self) -> Vec<u32> {
        let mut ids = self
            .changed
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default();
        ids.sort_unstable();
        ids.dedup();
        ids
    }

    /// The slots of M each patch `ids[i]` spans now (holes among its
    /// triangles included); `None` for a patch that lost all its triangles.
    pub fn ranges(&self, ids: &[u32]) -> Vec<Option<std::ops::Range<usize>>> {
        let starts = self.starts();
        ids.iter()
            .map(|id| {
                let i = self.patches.binary_search_by_key(id, |p| p.id).ok()?;
                let p = &self.patches[i];
                (p.len > 0).then(|| starts[i]..starts[i] + p.slots)
            })
            .collect()
    }

    /// Accounts for a starting mesh of `triangles`, never simplified.
    pub fn start(&mut self, triangles: usize) {
        if triangles > 0 {
            let id = self.new_id();
            self.patches.push(Patch {
                id,
                len: triangles,
                slots: triangles,
                pose: None,
                changed: 0,
                done: true,
            });
        }
    }

    /// Accounts for `triangles` appended at `iteration`, seen from `pose`.
    pub fn added(&mut self, triangles: usize, pose: &Pose, iteration: u32) {
        if triangles > 0 {
            let id = self.new_id();
            self.patches.push(Patch {
                id,
                len: triangles,
                slots: triangles,
                pose: Some(*pose),
                changed: iteration,
                done: false,
            });
        }
    }

    /// The first slot of the patch holding slot `t`.
    pub fn start_of(&self, t: usize) -> usize {
        let mut start = 0;
        for p in &self.patches {
            if t < start + p.slots {
                break;
            }
            start += p.slots;
        }
        start
    }

    /// Accounts for the triangles in slots `removed` (ascending) becoming
    /// holes at `iteration`.
    pub fn lost(&mut self, iteration: u32, removed: &[usize]) {
        let mut rest = removed;
        let mut end = 0;
        for p in &mut self.patches {
            end += p.slots;
            let n = rest.partition_point(|&t| t < end);
            if n == 0 {
                continue;
            }
            rest = &rest[n..];
            // Noise takes a spike now and then; a patch losing a real
            // part of itself is changing.
            if n * 100 >= p.len {
                p.changed = iteration;
            }
            p.len -= n;
            if let Some(changed) = &mut self.changed {
                changed.push(p.id);
            }
        }
    }

    /// Accounts for M closed up: every patch spans its triangles only, and
    /// those left with none are gone.
    pub fn closed(&mut self) {
        for p in &mut self.patches {
            p.slots = p.len;
        }
        self.patches.retain(|p| p.len > 0);
    }

    /// Simplifies the patches settled at `iteration` (see the module docs);
    /// `votes` are the removal votes per triangle (empty without removal)
    /// and are kept in step. Says what changed, if anything did.
    pub fn settle(
        &mut self,
        mesh: &mut Mesh,
        votes: &mut Vec<u8>,
        iteration: u32,
        settling: &Settling,
        novelty: Threshold,
    ) -> Result<Option<Settled>> {
        if !votes.is_empty() {
            votes.resize(mesh.triangle_count(), 0); // the triangles added since the render
        }
        let starts = self.starts();
        let ready: Vec<usize> = (0..self.patches.len())
            .filter(|&i| {
                let p = &self.patches[i];
                !p.done && p.len > 0 && iteration.saturating_sub(p.changed) >= settling.after
            })
            .collect();
        if ready.is_empty() {
            return Ok(None);
        }
        // Every group of every ready patch, simplified in parallel.
        // Groups hold GROUP triangles whatever holes lie between them, so a
        // map closed up (saved and resumed) settles into the same groups.
        let mut jobs: Vec<(usize, std::ops::Range<usize>)> = Vec::new();
        for &i in &ready {
            let (start, end) = (starts[i], starts[i] + self.patches[i].slots);
            let size = group_size(self.patches[i].len);
            let (mut from, mut live) = (start, 0);
            for t in start..end {
                live += usize::from(!is_hole(&mesh.triangles[t]));
                if live == size || t + 1 == end {
                    jobs.push((i, from..t + 1));
                    (from, live) = (t + 1, 0);
                }
            }
        }
        let seams: Vec<Seams> = ready
            .par_iter()
            .map(|&i| {
                let first = jobs.partition_point(|(j, _)| *j < i);
                let count = jobs[first..].partition_point(|(j, _)| *j == i);
                Seams::of(mesh, &jobs[first..first + count])
            })
            .collect();
        let mut parts = jobs
            .par_iter()
            .map(|(i, range)| {
                let pose = self.patches[*i]
                    .pose
                    .expect("only patches with a pose settle");
                let group = Group {
                    mesh,
                    seams: &seams[ready.partition_point(|&j| j < *i)],
                    votes,
                    range: range.clone(),
                };
                group.simplify(&pose, settling, novelty)
            })
            .collect::<Result<Vec<_>>>()?;
        let mut fewer = 0;
        // Back to front, so the patches not yet replaced keep their indices.
        for &i in ready.iter().rev() {
            let first = jobs.partition_point(|(j, _)| *j < i);
            let patch_parts: Vec<_> = parts.drain(first..).collect();
            let p = &mut self.patches[i];
            let count = replace(mesh, votes, starts[i]..starts[i] + p.slots, patch_parts);
            fewer += p.len - count;
            (p.len, p.slots, p.done) = (count, count, true);
            self.note(self.patches[i].id);
        }
        Ok(Some(Settled {
            fewer,
            first: starts[ready[0]],
        }))
    }
}

/// What one settling step did to M.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Settled {
    /// How many triangles fewer M has (the holes the simplified patches
    /// spanned are closed up too).
    pub fewer: usize,
    /// The first triangle index that changed (M is unchanged before it).
    pub first: usize,
}

/// Replaces the triangles `range` of `mesh` (and their votes) with `parts`,
/// returning how many triangles they became. The triangles in `range` must
/// be the only users of a contiguous run of vertices, which comes after the
/// vertices of every earlier triangle and before those of every later one:
/// M is built that way (each patch appends its own vertices), removal keeps
/// the order, and so does this.
fn replace(
    mesh: &mut Mesh,
    votes: &mut Vec<u8>,
    range: std::ops::Range<usize>,
    parts: Vec<(Mesh, Vec<u8>)>,
) -> usize {
    let (v0, v1) = vertex_span(&mesh.triangles[range.clone()]);
    let (mut positions, mut colors, mut triangles, mut new_votes) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (part, part_votes) in parts {
        let base = v0 + positions.len() as u32;
        triangles.extend(part.triangles.iter().map(|t| t.map(|v| v + base)));
        positions.extend_from_slice(&part.positions);
        colors.extend_from_slice(&part.colors);
        new_votes.extend_from_slice(&part_votes);
    }
    let (v0, v1) = (v0 as usize, v1 as usize);
    let shift = positions.len() as i64 - (v1 - v0) as i64;
    let count = triangles.len();
    mesh.positions.splice(v0..v1, positions);
    mesh.colors.splice(v0..v1, colors);
    mesh.triangles.splice(range.clone(), triangles);
    for t in &mut mesh.triangles[range.start + count..] {
        *t = t.map(|v| (v as i64 + shift) as u32);
    }
    if !votes.is_empty() {
        votes.splice(range, new_votes);
    }
    count
}

/// The lowest vertex `triangles` use and one past the highest (`(u32::MAX,
/// 0)` for none): a patch's, or a group's, vertices are a run of M's.
fn vertex_span(triangles: &[[u32; 3]]) -> (u32, u32) {
    triangles
        .iter()
        .flatten()
        .fold((u32::MAX, 0), |(lo, hi), &v| (lo.min(v), hi.max(v + 1)))
}

/// The vertices of a patch that more than one of its groups use.
struct Seams {
    /// The patch's first vertex (a patch's vertices are a contiguous run).
    first: u32,
    /// Per vertex of the patch from `first` on, whether it lies on a seam.
    shared: Vec<bool>,
}

impl Seams {
    /// The seams between `groups` (one patch's, as `(patch, triangles)`).
    fn of(mesh: &Mesh, groups: &[(usize, std::ops::Range<usize>)]) -> Seams {
        let triangles = |range: &std::ops::Range<usize>| mesh.triangles[range.clone()].iter();
        // The groups are consecutive: their span is the patch's.
        let (first, end) = match (groups.first(), groups.last()) {
            (Some((_, a)), Some((_, b))) => vertex_span(&mesh.triangles[a.start..b.end]),
            _ => (u32::MAX, 0),
        };
        let len = end.saturating_sub(first) as usize;
        let (mut group_of, mut shared) = (vec![usize::MAX; len], vec![false; len]);
        for (g, (_, range)) in groups.iter().enumerate() {
            for &v in triangles(range).flatten() {
                let i = (v - first) as usize;
                shared[i] |= group_of[i] != usize::MAX && group_of[i] != g;
                group_of[i] = g;
            }
        }
        Seams { first, shared }
    }

    /// Whether vertex `v` of the patch lies on a seam.
    fn contains(&self, v: u32) -> bool {
        self.shared[(v - self.first) as usize]
    }
}

/// A run of triangles of M to simplify on its own, with their removal votes.
struct Group<'a> {
    mesh: &'a Mesh,
    /// Its patch's seams, which stay where they are.
    seams: &'a Seams,
    /// Votes of all of M's triangles (empty without removal).
    votes: &'a [u8],
    range: std::ops::Range<usize>,
}

impl Group<'_> {
    /// Simplifies the group, seen from `pose`, with its seams with the
    /// patch's other groups locked; returns it as a mesh of its own with
    /// the votes of its triangles.
    /// Triangles holding votes are kept as they are (their corners locked)
    /// and keep their votes; every new triangle starts with none.
    fn simplify(
        &self,
        pose: &Pose,
        settling: &Settling,
        novelty: Threshold,
    ) -> Result<(Mesh, Vec<u8>)> {
        let mesh = self.mesh;
        let mut local = Mesh::default();
        // The group's vertices are a run of M's (a patch's vertices are), so
        // their new indices are looked up by offset in that run.
        let (first, end) = vertex_span(&mesh.triangles[self.range.clone()]);
        let mut index = vec![u32::MAX; end.saturating_sub(first) as usize];
        let mut locked = Vec::new();
        let mut voted = HashMap::new();
        let to_camera = pose.inverse();
        let mut nearest = f32::INFINITY;
        for t in self.range.clone() {
            if is_hole(&mesh.triangles[t]) {
                continue;
            }
            let vote = self.votes.get(t).copied().unwrap_or(0);
            let tri = mesh.triangles[t].map(|v| {
                let i = &mut index[(v - first) as usize];
                if *i == u32::MAX {
                    let p = mesh.positions[v as usize];
                    nearest = nearest.min(to_camera.transform_point(p).z);
                    local.positions.push(p);
                    local.colors.push(mesh.colors[v as usize]);
                    locked.push(self.seams.contains(v));
                    *i = local.positions.len() as u32 - 1;
                }
                locked[*i as usize] |= vote > 0;
                *i
            });
            if vote > 0 {
                voted.insert(corner_key(&local, &tri), vote);
            }
            local.triangles.push(tri);
        }
        if local.triangles.is_empty() {
            return Ok((local, Vec::new())); // holes only
        }
        let bound = settling.error * novelty.at(nearest.max(0.0));
        let params = SimplifyParams {
            target: None,
            max_error: Some(bound),
            lock_border: false,
        };
        let out = if bound > 0.0 {
            simplify_locked(&local, &locked, &params)?.mesh
        } else {
            local
        };
        // Locked corners do not move, so a voted triangle is found again by them.
        let votes = out
            .triangles
            .iter()
            .map(|t| voted.get(&corner_key(&out, t)).copied().unwrap_or(0))
            .collect();
        Ok((out, votes))
    }
}

/// A triangle's corner positions, bit for bit, as a key.
fn corner_key(mesh: &Mesh, t: &[u32; 3]) -> [[u32; 3]; 3] {
    t.map(|v| mesh.positions[v as usize].to_array().map(f32::to_bits))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// A flat `n × n` grid 2 m in front of the identity pose, coloured by vertex.
    fn grid(n: u32) -> Mesh {
        let mut mesh = Mesh::default();
        for r in 0..n {
            for c in 0..n {
                mesh.positions
                    .push(Vec3::new(c as f32 * 0.004, r as f32 * 0.004, 2.0));
                mesh.colors.push([(r % 7) as u8, (c % 5) as u8, 9]);
            }
        }
        for r in 0..n - 1 {
            for c in 0..n - 1 {
                let i = r * n + c;
                mesh.triangles.push([i, i + n, i + 1]);
                mesh.triangles.push([i + 1, i + n, i + n + 1]);
            }
        }
        mesh
    }

    #[test]
    fn a_settled_patch_shrinks_keeping_colours_votes_and_outline() {
        let mut mesh = grid(60);
        let original = mesh.clone();
        let mut votes = vec![0u8; mesh.triangle_count()];
        votes[1000] = 1;
        let voted = corner_key(&mesh, &mesh.triangles[1000]);
        let mut patches = Patches::default();
        patches.added(mesh.triangle_count(), &Pose::IDENTITY, 1);
        let settling = Settling {
            after: 3,
            error: 0.2,
        };
        let t = Threshold::Metres(0.01);
        let early = patches
            .settle(&mut mesh, &mut votes, 3, &settling, t)
            .unwrap();
        assert_eq!(early, None, "not settled before `after` iterations");
        let settled = patches
            .settle(&mut mesh, &mut votes, 4, &settling, t)
            .unwrap()
            .unwrap();
        assert_eq!(settled.first, 0);
        assert_eq!(
            settled.fewer,
            original.triangle_count() - mesh.triangle_count()
        );
        // The outline (236 border vertices) is kept, the inside collapses.
        assert!(mesh.triangle_count() < original.triangle_count() / 10);
        mesh.check().unwrap();
        assert_eq!(votes.len(), mesh.triangle_count());
        let kept_vote: Vec<_> = (0..mesh.triangle_count())
            .filter(|&i| votes[i] > 0)
            .map(|i| corner_key(&mesh, &mesh.triangles[i]))
            .collect();
        assert_eq!(kept_vote, vec![voted], "the voted triangle keeps its vote");
        // Kept vertices keep their colours and stay on the plane.
        for (p, c) in mesh.positions.iter().zip(&mesh.colors) {
            let i = original.positions.iter().position(|q| q == p);
            let i = i.expect("a flat grid's vertices do not move");
            assert_eq!(original.colors[i], *c);
        }
        // Settled once: nothing more to do.
        let again = patches
            .settle(&mut mesh, &mut votes, 10, &settling, t)
            .unwrap();
        assert_eq!(again, None);
    }
}
