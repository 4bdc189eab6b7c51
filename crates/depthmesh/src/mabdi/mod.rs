//! MABDI — Mesh Addition Based on the Depth Image (Chavez 2016): grow a global
//! mesh only where the sensor sees what the mesh does not already predict.
//!
//! Per frame: render the expected depth E of the global mesh M from the
//! sensor's pose ([`crate::raster`]), classify the pixels of D
//! ([`classify`](mod@classify)), mesh the novel pixels only ([`mesher`]) and append that
//! surface S to M, coloured by iteration. Beyond the thesis, triangles the
//! sensor sees through are removed ([`removal`]), and so are those where it
//! returns nothing while the same surface is seen through elsewhere
//! ([`absence`](mod@absence)); surface that has settled is simplified
//! ([`settle`]). [`NaiveMapper`] is the
//! thesis's "traditional method" that appends every frame's whole surface.

pub mod absence;
pub mod classify;
pub mod mesher;
pub mod removal;
pub mod rtin;
pub mod settle;
pub mod smooth;

use crate::camera::{Intrinsics, Pose};
use crate::error::{Error, Result};
use crate::image::{DepthImage, Frame};
use crate::map::{IntegrateReport, MapStats, Mapper};
use crate::mesh::Mesh;
use crate::palette::iteration_color;
use crate::raster::{is_hole, render_mesh_depth, ChunkBounds, Geometry, Rasterizer, RenderTarget};
use absence::MissingReturns;
use classify::{classify, PixelClass, Threshold};
use mesher::DepthMesher;
use removal::Carver;
use settle::{Patches, Settling};
use smooth::{Smoother, Smoothing};

/// Parameters of mesh addition.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MabdiConfig {
    /// Sensor intrinsics; frames must match their size.
    pub intrinsics: Intrinsics,
    /// `|D − E|` above this is novel (eq. 3.1).
    pub novelty: Threshold,
    /// Neighbouring depths further apart than this are a boundary (eq. 3.4).
    pub boundary: Threshold,
    /// Remove triangles the sensor sees through; `None` keeps everything (the thesis).
    pub removal: Option<RemovalConfig>,
    /// Mesh novel surface adaptively ([`rtin`]) and simplify surface that
    /// has settled ([`settle`]), both to `error · τ(z)`; `None` keeps the
    /// depth-image grid triangles as they were added (the thesis).
    pub settling: Option<Settling>,
    /// Mesh novel surface from D smoothed on each surface ([`smooth`]);
    /// `None` meshes the measurement as it came (the thesis).
    pub smoothing: Option<Smoothing>,
}

/// Parameters of object removal (see [`removal`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RemovalConfig {
    /// How far beyond a triangle the measurement must be to contradict it.
    pub threshold: Threshold,
    /// Contradicting frames, without a confirmation between them, that remove a triangle.
    pub frames: u8,
    /// Also count missing returns on surface that is seen through elsewhere
    /// ([`absence`](mod@absence)); `None` needs a measurement beyond every triangle.
    pub missing: Option<MissingReturns>,
}

impl Threshold {
    /// Rejects thresholds that are not positive and finite, naming `what`.
    fn validate(&self, what: &str) -> Result<()> {
        let ok = match *self {
            Threshold::Normalised { value, near, far } => {
                value > 0.0 && near > 0.0 && far > near && far.is_finite()
            }
            Threshold::Metres(m) => m > 0.0 && m.is_finite(),
        };
        if ok {
            Ok(())
        } else {
            Err(Error::parameter(
                what,
                format!("{self:?} is not a positive, finite threshold"),
            ))
        }
    }
}

impl MabdiConfig {
    /// Rejects settings that cannot work.
    pub fn validate(&self) -> Result<()> {
        self.intrinsics.validate()?;
        self.novelty.validate("novelty threshold")?;
        self.boundary.validate("boundary threshold")?;
        if let Some(s) = self.settling {
            if s.after == 0 {
                return Err(Error::parameter(
                    "settling iterations",
                    "must be at least 1",
                ));
            }
            if !(s.error > 0.0 && s.error < 1.0) {
                return Err(Error::parameter(
                    "settling error",
                    format!(
                        "must be a fraction of the novelty threshold in (0, 1), got {}",
                        s.error
                    ),
                ));
            }
        }
        if let Some(s) = self.smoothing {
            s.filter(self.novelty).validate()?;
        }
        if let Some(r) = self.removal {
            r.threshold.validate("removal threshold")?;
            if r.frames == 0 {
                return Err(Error::parameter("removal frames", "must be at least 1"));
            }
            if let Some(m) = r.missing {
                let [lo, hi] = m.range;
                if !(lo > 0.0 && hi > lo && hi.is_finite()) {
                    return Err(Error::parameter(
                        "missing-return range",
                        format!("need 0 < near < far metres, got {lo}..{hi}"),
                    ));
                }
                if m.seeds == 0 {
                    return Err(Error::parameter(
                        "missing-return seeds",
                        "must be at least 1",
                    ));
                }
                if m.fringe > 8 {
                    return Err(Error::parameter(
                        "missing-return fringe",
                        format!("at most 8 pixels, got {}", m.fringe),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The thesis's settings for a sensor with range `[near, far]` metres,
    /// with removal on. Removal needs the sensor to see at least
    /// 0.005 in normalised depth (≈ 0.005·z² m, 2.5σ of the thesis's noise)
    /// beyond a triangle at all nine pixels around it, in two frames: half the
    /// novelty threshold, so that objects standing on others lose all but
    /// their last few centimetres of contact at once. Missing returns count
    /// between 1.1·near and 0.875·far (0.88–3.5 m for 0.8–4 m: 15σ of the
    /// thesis's noise inside the far limit) on regions with 16 solidly
    /// seen-through pixels (a 4×4 patch; 2.6 mm² at 1 m, so any object the
    /// sensor can map shows that much somewhere once it is gone), and on
    /// pixels within 2 of those regions ([`absence`](mod@absence)).
    /// Surface unchanged for 3 iterations is simplified to 0.2·τ(z), σ of
    /// the thesis's noise. Novel surface is meshed from D smoothed over
    /// 5×5 pixels ([`smooth`]): with 3×3 the noisy bunnies' M was 29 %
    /// larger (255,409 triangles against 197,424) and 92.8 % of it within
    /// 5 mm against 96.3 %.
    pub fn thesis(intrinsics: Intrinsics, near: f32, far: f32) -> Self {
        let t = Threshold::thesis(near, far);
        MabdiConfig {
            intrinsics,
            novelty: t,
            boundary: t,
            removal: Some(RemovalConfig {
                threshold: Threshold::Normalised {
                    value: 0.005,
                    near,
                    far,
                },
                frames: 2,
                missing: Some(MissingReturns {
                    range: [1.1 * near, 0.875 * far],
                    seeds: 16,
                    fringe: 2,
                }),
            }),
            settling: Some(Settling {
                after: 3,
                error: 0.2,
            }),
            smoothing: Some(Smoothing { radius: 2 }),
        }
    }
}

/// What a MABDI map carries from frame to frame, to save and put back:
/// M, its iteration, the removal votes per triangle and M's patches.
#[derive(Clone, Debug, PartialEq)]
pub struct MabdiState {
    /// The global mesh M (positions, colours, triangles).
    pub mesh: Mesh,
    /// Frames integrated.
    pub iteration: u32,
    /// Removal votes per triangle (empty without removal).
    pub votes: Vec<u8>,
    /// M's patches (see [`settle::Patches::saved`]).
    pub patches: Vec<settle::SavedPatch>,
    /// The id the next patch gets.
    pub next_patch: u32,
}

/// The MABDI map: a global mesh grown by novel surface only.
#[derive(Debug)]
pub struct MabdiMapper {
    config: MabdiConfig,
    mesh: Mesh,
    iteration: u32,
    rasterizer: Rasterizer,
    expected: RenderTarget,
    classes: Vec<PixelClass>,
    mesher: DepthMesher,
    smoother: Smoother,
    carver: Carver,
    /// M's triangles by the iteration that added them, for simplification.
    patches: Patches,
    /// Scratch for closing up: new vertex indices.
    remap: Vec<u32>,
    /// Scratch for removal: the triangles removed this frame.
    removed: Vec<usize>,
    /// Boxes of M's triangle chunks, so E skips what is out of view.
    chunks: ChunkBounds,
}

/// Checks a frame against the configured sensor.
fn check_frame(frame: &Frame, intrinsics: &Intrinsics) -> Result<()> {
    if frame.depth.data.len() != intrinsics.pixel_count() {
        return Err(Error::parameter(
            format!("frame {}", frame.index),
            format!(
                "depth image holds {} values for {}×{} pixels",
                frame.depth.data.len(),
                frame.depth.width,
                frame.depth.height
            ),
        ));
    }
    if frame.depth.width != intrinsics.width || frame.depth.height != intrinsics.height {
        return Err(Error::parameter(
            format!("frame {}", frame.index),
            format!(
                "depth image is {}×{} but the camera is {}×{}",
                frame.depth.width, frame.depth.height, intrinsics.width, intrinsics.height
            ),
        ));
    }
    Ok(())
}

impl MabdiMapper {
    /// An empty map.
    pub fn new(config: MabdiConfig) -> Result<Self> {
        Self::with_mesh(config, Mesh::default())
    }

    /// A map that starts from an existing global mesh (e.g. a saved map).
    /// Its normals are dropped (added surface has none) and, if it has no
    /// colours, it is shown in grey rather than in an iteration's colour.
    pub fn with_mesh(config: MabdiConfig, mut mesh: Mesh) -> Result<Self> {
        config.validate()?;
        mesh.check().map_err(|m| Error::parameter("mesh", m))?;
        mesh.normals.clear();
        if mesh.colors.is_empty() {
            mesh.colors = vec![[160, 160, 160]; mesh.positions.len()];
        }
        let mut chunks = ChunkBounds::default();
        chunks.extend(&mesh.positions, &mesh.triangles);
        let mut patches = Patches::default();
        patches.start(mesh.triangle_count());
        Ok(MabdiMapper {
            config,
            mesh,
            iteration: 0,
            rasterizer: Rasterizer::new(),
            expected: RenderTarget::depth_only(),
            classes: Vec::new(),
            mesher: DepthMesher::new(),
            smoother: Smoother::default(),
            carver: Carver::default(),
            patches,
            remap: Vec::new(),
            removed: Vec::new(),
            chunks,
        })
    }

    /// The map's state, to save (a copy, closed up).
    pub fn state(&self) -> MabdiState {
        let (mut mesh, mut votes, mut patches) = (
            self.mesh.clone(),
            self.carver.votes.clone(),
            self.patches.clone(),
        );
        close_up(&mut mesh, &mut votes, &mut patches, &mut Vec::new());
        let (patches, next_patch) = patches.saved();
        MabdiState {
            mesh,
            iteration: self.iteration,
            votes,
            patches,
            next_patch,
        }
    }

    /// Puts back a saved state: the map continues as the one that saved it.
    pub fn restore(&mut self, state: MabdiState) -> Result<()> {
        state
            .mesh
            .check()
            .map_err(|m| Error::parameter("saved mesh", m))?;
        let patches = settle::Patches::restore(&state.patches, state.next_patch);
        let triangles = state.mesh.triangle_count();
        let votes_fit = state.votes.is_empty() || state.votes.len() == triangles;
        if patches.slots() != triangles || !votes_fit {
            return Err(Error::parameter(
                "saved map",
                "its patches or votes do not cover its triangles",
            ));
        }
        self.mesh = state.mesh;
        self.iteration = state.iteration;
        self.carver.votes = state.votes;
        self.patches = patches;
        self.chunks = ChunkBounds::default();
        self.chunks
            .extend(&self.mesh.positions, &self.mesh.triangles);
        Ok(())
    }

    /// The expected depth image E of the last frame.
    pub fn expected(&self) -> &DepthImage {
        &self.expected.depth
    }

    /// The pixel classes of the last frame.
    pub fn classes(&self) -> &[PixelClass] {
        &self.classes
    }

    /// The global mesh M as it is held: it may have holes (see [`is_hole`]),
    /// which cover nothing; [`Mapper::mesh`] closes them up.
    pub fn mesh_ref(&self) -> &Mesh {
        &self.mesh
    }

    /// Starts noting changed patches for a viewer, which receives M patch
    /// by patch (an iteration's novel surface each); returns every patch's id.
    pub fn follow_patches(&mut self) -> Vec<u32> {
        self.patches.follow()
    }

    /// The patches added, changed (removal, simplification) or emptied
    /// since the last call (or [`MabdiMapper::follow_patches`]).
    pub fn changed_patches(&mut self) -> Vec<u32> {
        self.patches.take_changed()
    }

    /// The mesh of each patch `ids[i]` now: empty for one that lost all
    /// its triangles.
    pub fn patch_meshes(&self, ids: &[u32]) -> Vec<Mesh> {
        self.patches
            .ranges(ids)
            .into_iter()
            .map(|r| {
                r.map_or_else(Mesh::default, |r| {
                    let mut patch = self.mesh.triangle_range(r);
                    patch.triangles.retain(|t| !is_hole(t));
                    patch.remove_unreferenced_vertices();
                    patch
                })
            })
            .collect()
    }

    /// Turns the triangles whose removal votes reached the limit into
    /// holes (see [`is_hole`]), so that a removal costs what it removes
    /// rather than moving every later triangle; M is closed up once an
    /// eighth of its slots are holes.
    fn remove_contradicted(&mut self, frames: u8) -> usize {
        let removed = &mut self.removed;
        removed.clear();
        for (t, vote) in self.carver.votes.iter_mut().enumerate() {
            if *vote >= frames {
                removed.push(t);
                *vote = 0;
                let tri = &mut self.mesh.triangles[t];
                *tri = [tri[0]; 3];
            }
        }
        self.patches.lost(self.iteration, removed);
        let slots = self.mesh.triangles.len();
        if slots - self.patches.triangles() > slots / 8 {
            self.close_up();
        }
        self.removed.len()
    }

    /// Closes up M's holes now (see [`close_up`]).
    fn close_up(&mut self) {
        if let Some(start) = close_up(
            &mut self.mesh,
            &mut self.carver.votes,
            &mut self.patches,
            &mut self.remap,
        ) {
            self.chunks.truncate(start);
            self.chunks
                .extend(&self.mesh.positions, &self.mesh.triangles);
        }
    }
}

/// Drops the holes of `mesh` (see [`is_hole`]) with their `votes` (empty
/// without removal) and the vertices left unused, and tells `patches`.
/// Only the patches from the one holding the first hole on are touched:
/// M's vertices come in patch order, so earlier patches use none of theirs.
/// Returns the first triangle that moved, if any did; `remap` is scratch.
fn close_up(
    mesh: &mut Mesh,
    votes: &mut Vec<u8>,
    patches: &mut Patches,
    remap: &mut Vec<u32>,
) -> Option<usize> {
    if patches.triangles() == mesh.triangles.len() {
        return None; // no holes: no need to look for one
    }
    let first = mesh.triangles.iter().position(is_hole)?;
    let start = patches.start_of(first);
    if !votes.is_empty() {
        votes.resize(mesh.triangles.len(), 0); // triangles added since the render have none
    }
    let mut kept = start;
    for t in start..mesh.triangles.len() {
        if !is_hole(&mesh.triangles[t]) {
            mesh.triangles[kept] = mesh.triangles[t];
            if !votes.is_empty() {
                votes[kept] = votes[t];
            }
            kept += 1;
        }
    }
    mesh.triangles.truncate(kept);
    votes.truncate(kept);
    patches.closed();
    compact_vertices(mesh, start, remap);
    Some(start)
}

/// Drops the vertices no triangle uses, given that the triangles before
/// `start` use only vertices before those of the triangles from `start` on;
/// `remap` is scratch.
fn compact_vertices(mesh: &mut Mesh, start: usize, remap: &mut Vec<u32>) {
    let tail = &mut mesh.triangles[start..];
    let Some(first) = tail.iter().flatten().min().map(|&v| v as usize) else {
        mesh.positions.truncate(
            mesh.triangles
                .iter()
                .flatten()
                .max()
                .map_or(0, |&v| v as usize + 1),
        );
        mesh.colors.truncate(mesh.positions.len());
        return;
    };
    remap.clear();
    remap.resize(mesh.positions.len() - first, u32::MAX);
    for &v in tail.iter().flatten() {
        remap[v as usize - first] = 0;
    }
    let mut next = first;
    for (i, r) in remap.iter_mut().enumerate() {
        if *r == 0 {
            *r = next as u32;
            mesh.positions[next] = mesh.positions[first + i];
            mesh.colors[next] = mesh.colors[first + i];
            next += 1;
        }
    }
    mesh.positions.truncate(next);
    mesh.colors.truncate(next);
    for t in tail.iter_mut() {
        *t = t.map(|v| remap[v as usize - first]);
    }
}

impl Mapper for MabdiMapper {
    fn name(&self) -> &'static str {
        "mabdi"
    }

    fn integrate(&mut self, frame: &Frame, pose: &Pose) -> Result<IntegrateReport> {
        let k = self.config.intrinsics;
        check_frame(frame, &k)?;
        self.iteration += 1;
        let clock = std::time::Instant::now();
        let mut lap = {
            let mut last = clock.elapsed();
            move || {
                let now = clock.elapsed();
                let ms = (now - last).as_secs_f64() * 1e3;
                last = now;
                ms
            }
        };
        // E is rendered with a tiny near plane: surface of M closer than the
        // sensor's minimum range still hides what is behind it. The removal
        // evidence is gathered in the same pass over M's triangles.
        let geometry = Geometry {
            positions: &self.mesh.positions,
            triangles: &self.mesh.triangles,
            chunks: Some(&self.chunks),
        };
        let mut to_remove = match self.config.removal {
            Some(removal) => {
                let (votes, evidence) = self.carver.prepare(
                    &frame.depth,
                    geometry.triangles.len(),
                    removal.threshold,
                    removal.frames,
                );
                self.rasterizer.render_visiting(
                    geometry,
                    &k,
                    pose,
                    0.01,
                    &mut self.expected,
                    Some(votes),
                    |v, s| evidence.judge(v, s),
                )
            }
            None => self.rasterizer.render_visiting(
                geometry,
                &k,
                pose,
                0.01,
                &mut self.expected,
                None,
                |_, _| false,
            ),
        };
        let render_ms = lap();
        let mut vanishing = false;
        if let Some(
            removal @ RemovalConfig {
                missing: Some(missing),
                ..
            },
        ) = self.config.removal
        {
            let (votes, absence) = self.carver.absence(
                &self.expected.depth,
                removal.threshold,
                self.config.boundary,
                &missing,
                removal.frames,
            );
            if let Some(absence) = absence {
                vanishing = true;
                to_remove |= self
                    .rasterizer
                    .visit_in_view(&self.mesh.triangles, votes, |v, s| absence.judge(v, s));
            }
        }
        let absence_ms = lap();
        let novel_pixels = classify(
            &frame.depth,
            &self.expected.depth,
            self.config.novelty,
            self.config.boundary,
            &mut self.classes,
        );
        let naive = DepthMesher::count(&self.classes, k.width, |c| {
            c != PixelClass::Invalid && c != PixelClass::Boundary
        });
        let classify_ms = lap();
        let removed = match self.config.removal {
            Some(removal) if to_remove => self.remove_contradicted(removal.frames),
            _ => 0,
        };
        let removal_ms = lap();
        let depth = match self.config.smoothing {
            Some(smoothing) if novel_pixels > 0 => {
                self.smoother
                    .apply(&frame.depth, &self.classes, smoothing, self.config.novelty)?
            }
            _ => &frame.depth,
        };
        let smooth_ms = lap();
        let added = append_novel(
            &mut self.mesher,
            &mut self.mesh,
            depth,
            &self.classes,
            &k,
            pose,
            self.iteration,
            self.config
                .settling
                .map(|s| s.mesher_bound(self.config.novelty)),
        );
        self.patches.added(added, pose, self.iteration);
        let mesh_ms = lap();
        let simplified = match &self.config.settling {
            Some(settling) => self.patches.settle(
                &mut self.mesh,
                &mut self.carver.votes,
                self.iteration,
                settling,
                self.config.novelty,
            )?,
            None => None,
        };
        if let Some(settled) = simplified {
            self.chunks.truncate(settled.first);
        }
        self.chunks
            .extend(&self.mesh.positions, &self.mesh.triangles);
        let settle_ms = lap();
        Ok(IntegrateReport {
            new_elements: added,
            removed_elements: removed,
            extra: vec![
                ("novel_pixels", novel_pixels as f64),
                ("naive_elements", naive as f64),
                ("render_ms", render_ms),
                ("absence_ms", absence_ms),
                ("vanishing", vanishing as u8 as f64),
                ("classify_ms", classify_ms),
                ("removal_ms", removal_ms),
                ("smooth_ms", smooth_ms),
                ("mesh_ms", mesh_ms),
                (
                    "simplified_elements",
                    simplified.map_or(0, |s| s.fewer) as f64,
                ),
                ("settle_ms", settle_ms),
            ],
        })
    }

    fn render_depth(&self, intrinsics: &Intrinsics, pose: &Pose) -> DepthImage {
        render_mesh_depth(&self.mesh, intrinsics, pose)
    }

    fn mesh(&mut self) -> &Mesh {
        self.close_up();
        &self.mesh
    }

    /// The triangles of M (holes not counted) and the vertices it holds
    /// (until M is closed up, some no triangle uses any more).
    fn stats(&self) -> MapStats {
        MapStats {
            elements: self.patches.triangles(),
            ..mesh_stats(&self.mesh)
        }
    }
}

/// Meshes the novel pixels of a frame's `depth` onto the end of `mesh`, in
/// the colour of `iteration`, adaptively within `bound` (metres `a + b·z²`
/// at depth z) if given, else in half pixels as the thesis does; returns how
/// many triangles were added.
#[allow(clippy::too_many_arguments)]
fn append_novel(
    mesher: &mut DepthMesher,
    mesh: &mut Mesh,
    depth: &DepthImage,
    classes: &[PixelClass],
    intrinsics: &Intrinsics,
    pose: &Pose,
    iteration: u32,
    bound: Option<(f32, f32)>,
) -> usize {
    let novel = |c| c == PixelClass::Novel;
    let (positions, triangles) = (&mut mesh.positions, &mut mesh.triangles);
    let added = match bound {
        Some(bound) => mesher.mesh_adaptive(
            depth, classes, novel, bound, intrinsics, pose, positions, triangles,
        ),
        None => mesher.mesh(
            depth, classes, novel, intrinsics, pose, positions, triangles,
        ),
    };
    mesh.colors
        .resize(mesh.positions.len(), iteration_color(iteration));
    added
}

/// Size of a mesh map: 12 bytes a vertex position, 3 of colour, 12 a triangle.
fn mesh_stats(mesh: &Mesh) -> MapStats {
    MapStats {
        elements: mesh.triangle_count(),
        vertices: Some(mesh.vertex_count()),
        bytes: mesh.positions.len() * 15 + mesh.triangles.len() * 12,
    }
}

/// The thesis's "traditional method": every frame's whole surface (valid,
/// non-boundary pixels) is appended to the map.
#[derive(Debug)]
pub struct NaiveMapper {
    config: MabdiConfig,
    mesh: Mesh,
    iteration: u32,
    classes: Vec<PixelClass>,
    mesher: DepthMesher,
    /// An all-empty expected image.
    nothing: DepthImage,
}

impl NaiveMapper {
    /// An empty map; only the intrinsics and the boundary threshold of `config` are used.
    pub fn new(config: MabdiConfig) -> Result<Self> {
        config.validate()?;
        Ok(NaiveMapper {
            config,
            mesh: Mesh::default(),
            iteration: 0,
            classes: Vec::new(),
            mesher: DepthMesher::new(),
            nothing: DepthImage::default(),
        })
    }

    /// The map's mesh.
    pub fn mesh_ref(&self) -> &Mesh {
        &self.mesh
    }

    /// The pixel classes of the last frame.
    pub fn classes(&self) -> &[PixelClass] {
        &self.classes
    }
}

impl Mapper for NaiveMapper {
    fn name(&self) -> &'static str {
        "naive"
    }

    fn integrate(&mut self, frame: &Frame, pose: &Pose) -> Result<IntegrateReport> {
        let k = self.config.intrinsics;
        check_frame(frame, &k)?;
        self.iteration += 1;
        // Against an empty prediction every valid, non-boundary pixel is novel.
        if self.nothing.data.len() != frame.depth.data.len() {
            self.nothing = DepthImage::new(k.width, k.height);
        }
        let novel_pixels = classify(
            &frame.depth,
            &self.nothing,
            self.config.novelty,
            self.config.boundary,
            &mut self.classes,
        );
        let added = append_novel(
            &mut self.mesher,
            &mut self.mesh,
            &frame.depth,
            &self.classes,
            &k,
            pose,
            self.iteration,
            None,
        );
        Ok(IntegrateReport {
            new_elements: added,
            removed_elements: 0,
            extra: vec![
                ("novel_pixels", novel_pixels as f64),
                ("naive_elements", added as f64),
            ],
        })
    }

    fn render_depth(&self, intrinsics: &Intrinsics, pose: &Pose) -> DepthImage {
        render_mesh_depth(&self.mesh, intrinsics, pose)
    }

    fn mesh(&mut self) -> &Mesh {
        &self.mesh
    }

    fn stats(&self) -> MapStats {
        mesh_stats(&self.mesh)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_that_cannot_work_are_rejected_by_name() {
        let ok = MabdiConfig::thesis(Intrinsics::from_vertical_fov(64, 48, 60.0), 0.8, 4.0);
        assert!(ok.validate().is_ok());
        let bad = |change: fn(&mut MabdiConfig)| {
            let mut c = ok;
            change(&mut c);
            c.validate().unwrap_err().to_string()
        };
        assert!(bad(|c| c.smoothing = Some(Smoothing { radius: 0 })).contains("radius"));
        assert!(bad(|c| c.smoothing = Some(Smoothing { radius: 40 })).contains("radius"));
        let e = bad(|c| {
            if let Some(r) = &mut c.removal {
                r.missing = r.missing.map(|m| MissingReturns { fringe: 9, ..m });
            }
        });
        assert!(e.contains("fringe"), "{e}");
        assert!(bad(|c| c.settling = Some(Settling {
            after: 3,
            error: 1.5
        }))
        .contains("settling error"));
    }
}
