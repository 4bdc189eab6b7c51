//! A mesh that grows too large to hold, kept on disk as numbered chunk files.
//!
//! Pieces of mesh handed out during a run (the blocks a bounded TSDF evicts)
//! gather in memory until the next would take a chunk past the vertex limit;
//! the chunk is then written, atomically, as `chunk-NNNNNN.ply` in global
//! coordinates, so memory holds at most one chunk. At the end, the chunks and
//! whatever is still in memory can be joined into one PLY file, streamed from
//! the chunk files one at a time.

use super::chunk::split_by_vertices;
use super::ply::{read_ply, write_ply, write_ply_joined, PlyFormat, PlyLayout};
use super::Mesh;
use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// Chunk files being written into one folder.
#[derive(Debug)]
pub struct ChunkFiles {
    dir: PathBuf,
    max_vertices: usize,
    pending: Mesh,
    files: Vec<PathBuf>,
    /// Totals over the written files.
    layout: PlyLayout,
}

impl ChunkFiles {
    /// Starts writing chunks of at most `max_vertices` vertices into `dir`
    /// (created if missing); chunk files of an earlier run there are removed,
    /// so the folder only ever describes one run.
    pub fn create(dir: &Path, max_vertices: usize) -> Result<Self> {
        if max_vertices < 3 {
            return Err(Error::parameter(
                "chunk vertices",
                format!("a chunk needs room for a triangle (3 vertices), got {max_vertices}"),
            ));
        }
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        for entry in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
            let path = entry.map_err(|e| Error::io(dir, e))?.path();
            let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
            if name.starts_with("chunk-") && name.ends_with(".ply") {
                std::fs::remove_file(&path).map_err(|e| Error::io(&path, e))?;
            }
        }
        Ok(ChunkFiles {
            dir: dir.to_path_buf(),
            max_vertices,
            pending: Mesh::default(),
            files: Vec::new(),
            layout: PlyLayout::default(),
        })
    }

    /// Adds a piece of mesh; writes the pending chunk first if the piece
    /// would take it past the limit.
    pub fn push(&mut self, piece: &Mesh) -> Result<()> {
        if piece.triangles.is_empty() {
            return Ok(());
        }
        if self.pending.vertex_count() + piece.vertex_count() > self.max_vertices {
            self.flush()?;
        }
        self.pending.append(piece);
        if self.pending.vertex_count() > self.max_vertices {
            // One piece alone exceeds the limit: cut it spatially.
            let big = std::mem::take(&mut self.pending);
            for chunk in split_by_vertices(&big, self.max_vertices)? {
                self.write(&chunk.mesh)?;
            }
        }
        Ok(())
    }

    /// Writes the pending chunk, if any.
    pub fn flush(&mut self) -> Result<()> {
        let pending = std::mem::take(&mut self.pending);
        if !pending.triangles.is_empty() {
            self.write(&pending)?;
        }
        Ok(())
    }

    fn write(&mut self, mesh: &Mesh) -> Result<()> {
        let path = self
            .dir
            .join(format!("chunk-{:06}.ply", self.files.len() + 1));
        write_ply(&path, mesh, PlyFormat::BinaryLittleEndian)?;
        self.layout.vertices += mesh.vertex_count();
        self.layout.triangles += mesh.triangle_count();
        self.layout.normals = !mesh.normals.is_empty();
        self.layout.colors = !mesh.colors.is_empty();
        self.files.push(path);
        Ok(())
    }

    /// The chunk files written so far, in order.
    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }

    /// Vertices and triangles in the chunk files written so far.
    pub fn written(&self) -> PlyLayout {
        self.layout
    }

    /// Runs `f` on each written chunk, read back one at a time, then on `rest`.
    pub fn for_each(&self, rest: &Mesh, mut f: impl FnMut(&Mesh) -> Result<()>) -> Result<()> {
        for path in &self.files {
            f(&read_ply(path)?)?;
        }
        f(rest)
    }

    /// Writes one binary PLY at `path` holding the written chunks and then
    /// `rest`, in that order, without loading more than one chunk at a time.
    /// Call [`ChunkFiles::flush`] first to include the pending chunk.
    pub fn write_joined(&self, path: &Path, rest: &Mesh) -> Result<()> {
        let mut layout = self.layout;
        layout.vertices += rest.vertex_count();
        layout.triangles += rest.triangle_count();
        if self.files.is_empty() {
            layout = PlyLayout::of(rest);
        }
        // Reading errors are carried out of the writer's io::Error channel
        // with their own message, which names the chunk file.
        let mut failure = None;
        let result = write_ply_joined(path, layout, |emit| {
            let read = self.for_each(rest, |m| emit(m).map_err(|e| Error::io(path, e)));
            read.map_err(|e| {
                let message = e.to_string();
                failure = Some(e);
                std::io::Error::other(message)
            })
        });
        match (result, failure) {
            (_, Some(e)) => Err(e),
            (r, None) => r,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::io::read_mesh;
    use glam::Vec3;

    /// `n` separate triangles along x, with normals.
    fn strip(n: usize, x0: f32) -> Mesh {
        let mut m = Mesh::default();
        for i in 0..n {
            let x = x0 + i as f32;
            let base = m.positions.len() as u32;
            m.positions.extend([
                Vec3::new(x, 0.0, 0.0),
                Vec3::new(x + 1.0, 0.0, 0.0),
                Vec3::new(x, 1.0, 0.0),
            ]);
            m.normals.extend([Vec3::Z; 3]);
            m.triangles.push([base, base + 1, base + 2]);
        }
        m
    }

    #[test]
    fn chunks_stay_under_the_limit_and_join_back_in_order() {
        let dir = std::env::temp_dir().join(format!("depthmesh-chunks-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("chunk-000099.ply"), b"stale").unwrap();
        let mut files = ChunkFiles::create(&dir, 12).unwrap();
        let mut all = Mesh::default();
        for (i, n) in [2usize, 3, 1, 9, 0, 2].into_iter().enumerate() {
            let piece = strip(n, 10.0 * i as f32);
            files.push(&piece).unwrap();
            all.append(&piece);
        }
        files.flush().unwrap();
        assert!(!dir.join("chunk-000099.ply").exists());
        let mut read_back = 0;
        files
            .for_each(&Mesh::default(), |m| {
                assert!(m.vertex_count() <= 12);
                read_back += m.triangle_count();
                Ok(())
            })
            .unwrap();
        assert_eq!(read_back, 17);
        let rest = strip(2, 100.0);
        all.append(&rest);
        let joined_path = dir.join("joined.ply");
        files.write_joined(&joined_path, &rest).unwrap();
        let joined = read_mesh(&joined_path).unwrap();
        assert_eq!(joined, all);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
