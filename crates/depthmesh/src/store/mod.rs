//! A map store: one file that holds what a mapping session needs to go on
//! after a crash, written in checkpoints.
//!
//! The file is a [redb](https://docs.rs/redb) database: copy-on-write pages
//! with checksums, each commit made durable (fsynced) before it returns, so
//! a process killed at any instant leaves the store at its last checkpoint,
//! whole. Tables:
//!
//! | table | key | value |
//! |---|---|---|
//! | `meta` | name | `format` (u64), `identity` (JSON: settings, camera, dataset), `checkpoint` (JSON: frames integrated, dataset position, time), `tracking` (JSON: the tracker's state), `last_view` (TSDF: the last fused frame's pose and depth, from which ray casting for tracking starts), `resident` (TSDF with bounded memory: the keys of the blocks in memory, LZ4-compressed `i32` triples), `planes` (JSON: the grid's insertions), `mabdi` (JSON: iteration, patches, array lengths) |
//! | `blocks` | TSDF block coordinates | the block's distances, weights (and colours), LZ4-compressed ([`block_codec`]) |
//! | `cells` | voxel-plane cell, by allocation order | its key and voxel statistics, LZ4-compressed (`cells`) |
//! | `arrays` | (MABDI array, chunk number) | a chunk of M's positions, colours, triangles or removal votes, LZ4-compressed (`arrays`) |
//! | `records` | frame order | the frame's record (pose, timings, map size) as JSON ([`records`]) |
//! | `free_space` | region of the tracker's free space | its cells ([`FreeSpace::encode_region`]), LZ4-compressed |
//!
//! A checkpoint writes, in one transaction, what changed since the previous
//! one — the TSDF blocks fused into, the plane cells added to, the chunks of
//! M whose bytes differ, the regions of the tracker's free space its rays
//! changed — and the records since it, so its cost follows what
//! the frames changed, not the map's size. With bounded memory the store is
//! also where freed TSDF blocks go and come back from ([`archive`]); it then
//! holds the whole map, and a continued session loads only the blocks that
//! were in memory. The traditional (naive) back-end is not stored: its map
//! is every frame's surface, which a run can make again.

pub mod archive;
mod arrays;
pub mod block_codec;
mod cells;
pub mod checkpoints;
pub mod records;

use archive::{Shelf, StoreArchive, Waiting};

use crate::camera::Pose;
use crate::error::{Error, Result};
use crate::image::DepthImage;
use crate::session::{Backend, MapConfig, PoseState, Resumed, SavedMap, Session, SessionConfig};
use crate::track::clock::FrameClock;
use crate::track::free_space::FreeSpace;
use crate::track::TrackerState;
use crate::tsdf::archive::BlockArchive;
use crate::tsdf::mapper::TsdfMapper;
use rayon::prelude::*;
use redb::{Database, ReadableDatabase, ReadableTable, ReadableTableMetadata, TableDefinition};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// The store's format; a store of another format is refused.
pub const FORMAT: u64 = 1;

const META: TableDefinition<&str, &[u8]> = TableDefinition::new("meta");
const BLOCKS: TableDefinition<(i32, i32, i32), &[u8]> = TableDefinition::new("blocks");
const RECORDS: TableDefinition<u64, &[u8]> = TableDefinition::new("records");
const FREE_SPACE: TableDefinition<(i32, i32, i32), &[u8]> = TableDefinition::new("free_space");

/// An open store, written by checkpoints.
pub struct MapStore {
    db: Arc<Database>,
    /// The commit of the last checkpoint, running beside the frame loop.
    writing: Option<std::thread::JoinHandle<Result<usize>>>,
    /// Compressed bytes the commits so far wrote.
    written: usize,
    path: PathBuf,
    /// Frames fused at the last checkpoint, and freed blocks not committed yet.
    shelf: Arc<Mutex<Shelf>>,
    /// Planes: grid insertions at the last checkpoint.
    saved_inserts: u32,
    /// MABDI: the hashes of the chunks of M the store holds.
    hashes: arrays::Hashes,
    /// Whether the blocks hold colours.
    color: bool,
    /// Records written so far.
    saved_records: usize,
    /// Tracking: the frames of free space at the last checkpoint.
    saved_free_space: usize,
}

/// What a store holds: enough to continue the session it was written by.
pub struct Saved {
    /// The settings, camera and dataset it was written with.
    pub identity: Value,
    /// How many of the dataset's selected frames were read by then.
    pub position: usize,
    /// The session's state at the last checkpoint (with bounded memory,
    /// only the blocks that were in memory).
    pub session: Resumed,
    /// Blocks in the store (TSDF maps).
    pub stored_blocks: usize,
    /// Regions of the tracker's free space in the store.
    pub stored_regions: usize,
    /// With bounded memory, how many blocks were in memory.
    pub resident_blocks: Option<usize>,
    /// The hashes of the chunks of a MABDI map the store holds.
    hashes: arrays::Hashes,
}

/// What a checkpoint wrote.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Checkpoint {
    /// TSDF blocks or plane cells written (changed since the previous
    /// checkpoint); 0 for MABDI, whose chunks are chosen by the commit.
    pub blocks: usize,
    /// Bytes copied for the commit (compressed, for plane cells).
    pub bytes: usize,
    /// Milliseconds the frame loop was held up: waiting for the previous
    /// commit, and copying what changed (compressing and writing it runs
    /// on the commit's own thread; plane cells are compressed here).
    pub ms: f64,
}

/// The settings of `config` that a continued session must share with the
/// one that wrote a store, as JSON; `dataset` says where frames come from.
pub fn identity(config: &SessionConfig, dataset: Value) -> Result<Value> {
    let k = &config.intrinsics;
    let mut id = match &config.map {
        MapConfig::Tsdf(t) => {
            let c = &t.config;
            json!({
                "map": "tsdf",
                "voxel": c.voxel,
                "truncation": c.truncation,
                "max_weight": c.max_weight,
                "min_weight": c.min_weight,
                "color": c.color,
                "range": [t.range.0, t.range.1],
                "active_radius": t.active_radius,
            })
        }
        MapConfig::Planes(p) => json!({
            "map": "planes",
            "voxel": p.config.grid.voxel,
            "cell": p.config.grid.cell,
            "epsilon": p.config.epsilon,
        }),
        // Its settings as a whole (the camera in them is the session's).
        MapConfig::Mabdi(m) => json!({"map": "mabdi", "settings": format!("{m:?}")}),
        MapConfig::Naive(_) => {
            return Err(Error::parameter(
                "map",
                "the map store holds tsdf, planes and mabdi maps, not naive",
            ))
        }
    };
    let common = json!({
        "format": FORMAT,
        "camera": [k.width, k.height, k.fx, k.fy, k.cx, k.cy],
        // The tracker's settings as a whole: any change is refused.
        "tracking": config.tracking.as_ref().map(|t| format!("{t:?}")),
        "dataset": dataset,
    });
    if let (Some(id), Value::Object(common)) = (id.as_object_mut(), common) {
        id.extend(common);
    }
    Ok(id)
}

/// Writes a map's part of a checkpoint in the commit's transaction;
/// returns the (compressed) bytes it wrote.
type WriteFn =
    Box<dyn FnOnce(&redb::WriteTransaction) -> std::result::Result<usize, redb::Error> + Send>;

/// The part of a checkpoint that depends on the back-end, prepared on the
/// frame thread: what to write, run in the commit's transaction.
struct MapWrite {
    /// Frames the map had integrated.
    frames: u32,
    /// Blocks or cells written.
    units: usize,
    /// Bytes copied for the commit, before compression.
    bytes: usize,
    write: WriteFn,
}

impl MapStore {
    /// Creates a store at `path` for a session with `identity`; an existing
    /// file is refused (continue it, or remove it).
    pub fn create(path: &Path, identity: &Value) -> Result<Self> {
        if path.exists() {
            return Err(Error::format(
                path,
                "a store exists here: continue it with --resume, or remove it",
            ));
        }
        // Made under a temporary name and renamed once initialised, so a
        // crash while creating it leaves no half-made store behind.
        let mut temp = path.as_os_str().to_owned();
        temp.push(format!(".{}.tmp", std::process::id()));
        let temp = PathBuf::from(temp);
        let db = Database::create(&temp).map_err(|e| store_error(&temp, e))?;
        write(&db, &temp, |txn| {
            let mut meta = txn.open_table(META)?;
            meta.insert("format", FORMAT.to_le_bytes().as_slice())?;
            meta.insert("identity", identity.to_string().as_bytes())?;
            txn.open_table(BLOCKS)?;
            txn.open_table(RECORDS)?;
            txn.open_table(FREE_SPACE)?;
            txn.open_table(cells::CELLS)?;
            txn.open_table(arrays::ARRAYS)?;
            Ok(())
        })?;
        drop(db);
        std::fs::rename(&temp, path).map_err(|e| Error::io(path, e))?;
        let (store, _) = MapStore::open(path)?;
        Ok(store)
    }

    /// Opens the store at `path` and reads what it holds. A file that is not
    /// a store, a damaged one or one of another format is an error naming it.
    pub fn open(path: &Path) -> Result<(Self, Saved)> {
        Self::open_with(path, true)
    }

    /// [`MapStore::open`]; a TSDF map's blocks and the tracker's free space
    /// are read only when `blocks` (reading what a store holds, or meshing
    /// it a slab at a time, needs neither in memory; only a resume does).
    fn open_with(path: &Path, blocks: bool) -> Result<(Self, Saved)> {
        if !path.is_file() {
            return Err(Error::format(path, "no store here"));
        }
        let (db, saved) = without_panics(path, || {
            let mut db = Database::open(path).map_err(|e| store_error(path, e))?;
            // Every page's checksum, before anything is read: a damaged
            // page must be an error here, not a wrong map later.
            if !db.check_integrity().map_err(|e| store_error(path, e))? {
                return Err(Error::format(
                    path,
                    "map store: damaged (a page fails its checksum)",
                ));
            }
            let saved = read_saved(&db, path, blocks)?;
            Ok((db, saved))
        })?;
        let store = MapStore {
            db: Arc::new(db),
            writing: None,
            written: 0,
            path: path.to_path_buf(),
            shelf: Arc::new(Mutex::new(Shelf {
                saved_frames: saved.session.map.frames(),
                ..Shelf::default()
            })),
            color: colour(&saved.identity),
            saved_records: saved.session.records.len(),
            saved_free_space: saved
                .session
                .poses
                .as_ref()
                .and_then(|p| p.tracker.as_ref())
                .map_or(0, |t| t.free_space.frames()),
            saved_inserts: match &saved.session.map {
                SavedMap::Planes { inserts, .. } => *inserts,
                _ => 0,
            },
            hashes: saved.hashes.clone(),
        };
        Ok((store, saved))
    }

    /// The store as the archive of a bounded map
    /// ([`crate::tsdf::mapper::TsdfMapper::set_archive`]): the blocks it
    /// frees are committed with the checkpoints.
    pub fn archive(&self) -> StoreArchive {
        StoreArchive {
            db: self.db.clone(),
            path: self.path.clone(),
            shelf: self.shelf.clone(),
            color: self.color,
        }
    }

    /// Commits what changed since the last checkpoint: the blocks fused
    /// since, the records since, and `position` (dataset frames read). The
    /// changed blocks are copied and compressed here; the commit runs on a
    /// thread of its own while mapping goes on (the next checkpoint, or
    /// [`MapStore::finish`], waits for it), so the frame loop is held up by
    /// the copy, not by the disk.
    pub fn checkpoint(&mut self, session: &Session, position: usize) -> Result<Checkpoint> {
        let start = Instant::now();
        self.finish()?;
        let map = match session.backend() {
            Backend::Tsdf(t) => self.tsdf_write(t),
            Backend::Planes(p) => {
                let w = cells::write(p, self.saved_inserts);
                self.saved_inserts = p.grid().inserts();
                w
            }
            Backend::Mabdi(m) => arrays::write(m, self.hashes.clone()),
            Backend::Naive(_) => {
                return Err(Error::parameter(
                    "map",
                    "the map store holds tsdf, planes and mabdi maps, not naive",
                ))
            }
        };
        let first = self.saved_records;
        let rows: Vec<String> = session.records()[first..]
            .iter()
            .map(records::encode)
            .collect();
        let mut pose_state = session.pose_state();
        let tracking = pose_state.as_ref().map(|p| pose_state_json(p).to_string());
        // The regions of free space changed since the last checkpoint are
        // encoded on the commit's thread, from the state's copy (which
        // shares them with the tracker's until it changes them).
        let free_space = pose_state
            .as_mut()
            .and_then(|p| p.tracker.as_mut())
            .map(|t| std::mem::take(&mut t.free_space));
        let free_after = self.saved_free_space;
        if let Some(f) = &free_space {
            self.saved_free_space = f.frames();
        }
        let checkpoint = json!({
            "frames": map.frames,
            "position": position,
            "records": first + rows.len(),
            "unix_seconds": std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs()),
        })
        .to_string();
        let (db, path) = (self.db.clone(), self.path.clone());
        let (units, bytes, write_map) = (map.units, map.bytes, map.write);
        self.writing = Some(std::thread::spawn(move || {
            write(&db, &path, |txn| {
                let bytes = write_map(txn)?;
                let mut table = txn.open_table(RECORDS)?;
                for (i, row) in rows.iter().enumerate() {
                    table.insert((first + i) as u64, row.as_bytes())?;
                }
                let mut meta = txn.open_table(META)?;
                if let Some(tracking) = &tracking {
                    meta.insert("tracking", tracking.as_bytes())?;
                }
                if let Some(free_space) = &free_space {
                    let mut table = txn.open_table(FREE_SPACE)?;
                    for key in free_space.changed_after(free_after) {
                        if let Some(raw) = free_space.encode_region(key) {
                            let bytes = lz4_flex::compress_prepend_size(&raw);
                            table.insert((key.x, key.y, key.z), bytes.as_slice())?;
                        }
                    }
                }
                meta.insert("checkpoint", checkpoint.as_bytes())?;
                Ok(bytes)
            })
        }));
        self.saved_records = session.records().len();
        Ok(Checkpoint {
            blocks: units,
            bytes,
            ms: start.elapsed().as_secs_f64() * 1e3,
        })
    }

    /// A TSDF map's part of a checkpoint: the blocks changed since the last
    /// one, those freed since (bounded memory), which blocks are in memory,
    /// and the last fused view.
    fn tsdf_write(&mut self, t: &TsdfMapper) -> MapWrite {
        let volume = t.volume();
        let mut shelf = self.shelf.lock().unwrap_or_else(|e| e.into_inner());
        // Changed blocks, new ones included even if nothing was fused into
        // them yet: ray casting treats a block that is there but empty
        // otherwise than one that is not, so the continued map must hold the same.
        // Copied here, compressed on the commit's thread: the frame loop
        // waits for a copy only.
        let keys = volume.changed_after(shelf.saved_frames);
        let changed: Vec<(glam::IVec3, crate::tsdf::Block)> = keys
            .par_iter()
            .map(|key| {
                (
                    *key,
                    volume.block(*key).expect("changed blocks are held").clone(),
                )
            })
            .collect();
        // Blocks freed since, then the resident ones (newer where both).
        let mut blocks: Waiting = std::mem::take(&mut shelf.pending);
        let freed = blocks.len();
        blocks.extend(changed);
        let blocks = Arc::new(blocks);
        shelf.committing = blocks.clone();
        shelf.saved_frames = volume.frames();
        let bytes = blocks.len() * crate::tsdf::BLOCK_VOXELS * volume.config().bytes_per_voxel();
        let resident = t.archived().then(|| {
            let raw: Vec<u8> = volume
                .blocks()
                .iter()
                .flat_map(|b| b.key.to_array())
                .flat_map(i32::to_le_bytes)
                .collect();
            lz4_flex::compress_prepend_size(&raw)
        });
        let last_view = t.last_view().map(|(pose, depth)| view_bytes(pose, depth));
        MapWrite {
            frames: volume.frames(),
            units: keys.len() + freed,
            bytes,
            write: Box::new(move |txn| {
                let mut table = txn.open_table(BLOCKS)?;
                let mut bytes = Vec::new();
                let mut written = 0;
                for (key, block) in blocks.iter() {
                    block_codec::encode(block, &mut bytes);
                    written += bytes.len();
                    table.insert((key.x, key.y, key.z), bytes.as_slice())?;
                }
                let mut meta = txn.open_table(META)?;
                if let Some(view) = &last_view {
                    meta.insert("last_view", view.as_slice())?;
                }
                if let Some(resident) = &resident {
                    meta.insert("resident", resident.as_slice())?;
                }
                Ok(written)
            }),
        }
    }

    /// Waits for the last commit, then gives the space of the map's earlier
    /// versions back to the file system (a run's last step: it takes about
    /// as long as writing the store's live data once). Skipped while the
    /// store is also a bounded map's archive (in use). Returns the file's
    /// size before and after.
    pub fn compact(&mut self) -> Result<(u64, u64)> {
        self.finish()?;
        let before = self.file_bytes()?;
        if let Some(db) = Arc::get_mut(&mut self.db) {
            while db
                .compact()
                .map_err(|e| Error::format(&self.path, format!("map store: {e}")))?
            {}
        }
        Ok((before, self.file_bytes()?))
    }

    /// Compressed bytes of the map the commits finished so far wrote.
    pub fn bytes_written(&self) -> usize {
        self.written
    }

    /// The size of the store's file.
    pub fn file_bytes(&self) -> Result<u64> {
        std::fs::metadata(&self.path)
            .map(|m| m.len())
            .map_err(|e| Error::io(&self.path, e))
    }

    /// Waits for the last checkpoint's commit; its error, if it failed.
    pub fn finish(&mut self) -> Result<()> {
        let Some(handle) = self.writing.take() else {
            return Ok(());
        };
        self.written += handle
            .join()
            .unwrap_or_else(|_| Err(Error::format(&self.path, "map store: the commit failed")))?;
        // Committed: the store has those blocks now.
        self.shelf
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .committing = Arc::default();
        Ok(())
    }
}

impl Drop for MapStore {
    fn drop(&mut self) {
        // A run that stops early still leaves its last checkpoint committed.
        let _ = self.finish();
    }
}

/// Runs `f` in one write transaction of `db` (the store at `path`) and
/// commits it durably; what `f` returned.
fn write<T>(
    db: &Database,
    path: &Path,
    f: impl FnOnce(&redb::WriteTransaction) -> std::result::Result<T, redb::Error>,
) -> Result<T> {
    let run = || -> std::result::Result<T, redb::Error> {
        let txn = db.begin_write()?;
        let value = f(&txn)?;
        txn.commit()?;
        Ok(value)
    };
    run().map_err(|e| store_error(path, e))
}

/// Refuses to continue a store written with other settings, camera or
/// dataset, naming what differs.
pub fn check_identity(path: &Path, saved: &Value, wanted: &Value) -> Result<()> {
    let (Some(a), Some(b)) = (saved.as_object(), wanted.as_object()) else {
        return Err(Error::format(path, "the store's identity is not readable"));
    };
    let differs: Vec<String> = b
        .iter()
        .filter(|(k, v)| a.get(*k) != Some(v))
        .map(|(k, v)| {
            format!(
                "{k} is {} in the store but {v} now",
                a.get(k).map_or("missing".to_string(), Value::to_string)
            )
        })
        .collect();
    if differs.is_empty() {
        Ok(())
    } else {
        Err(Error::format(
            path,
            format!(
                "written by another run: {}; use the same settings, or a new store",
                differs.join("; ")
            ),
        ))
    }
}

/// Whether the file at `path` is a map store (by its first bytes: those of
/// every redb database).
pub fn is_store(path: &Path) -> bool {
    let mut head = [0u8; 9];
    std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut head))
        .is_ok_and(|()| head == *b"redb\x1A\x0A\xA9\x0D\x0A")
}

/// The mesh of the map a store holds at its last checkpoint: what the run
/// that wrote it would have written as `mesh.ply` had it ended there. Meshed
/// a slab at a time ([`crate::tsdf::archive::mesh_slabs`]), so only the
/// mesh, not the map, must fit in memory.
pub fn mesh(path: &Path) -> Result<crate::mesh::Mesh> {
    let (store, saved) = MapStore::open_with(path, false)?;
    let id = &saved.identity;
    let bad = |k: &str| Error::format(path, format!("identity: no {k}"));
    let number = |k: &str| id[k].as_f64().ok_or_else(|| bad(k));
    match saved.session.map {
        SavedMap::Tsdf { .. } => {}
        SavedMap::Mabdi(state) => return Ok(state.mesh),
        SavedMap::Planes {
            cells,
            frames,
            inserts,
        } => {
            use crate::planes::{PlaneGridConfig, PlanesConfig, PlanesMapper};
            let config = PlanesConfig {
                grid: PlaneGridConfig {
                    voxel: number("voxel")? as f32,
                    cell: number("cell")? as f32,
                },
                epsilon: number("epsilon")?,
            };
            let camera: Vec<f64> = id["camera"]
                .as_array()
                .map(|c| c.iter().filter_map(Value::as_f64).collect())
                .filter(|c: &Vec<f64>| c.len() == 6)
                .ok_or_else(|| bad("camera"))?;
            let k = crate::camera::Intrinsics {
                width: camera[0] as u32,
                height: camera[1] as u32,
                fx: camera[2] as f32,
                fy: camera[3] as f32,
                cx: camera[4] as f32,
                cy: camera[5] as f32,
            };
            let mut planes = PlanesMapper::new(config, k)?;
            planes.restore(cells, frames, inserts)?;
            return Ok(crate::map::Mapper::mesh(&mut planes).clone());
        }
    }
    let weight = |k: &str| {
        id[k]
            .as_u64()
            .and_then(|w| u16::try_from(w).ok())
            .ok_or_else(|| bad(k))
    };
    let config = crate::tsdf::TsdfConfig {
        voxel: number("voxel")? as f32,
        truncation: number("truncation")? as f32,
        max_weight: weight("max_weight")?,
        color: id["color"].as_bool().ok_or_else(|| bad("color"))?,
        min_weight: weight("min_weight")?,
    };
    drop(saved);
    let archive = store.archive();
    let mut mesh = crate::mesh::Mesh::default();
    crate::tsdf::archive::mesh_slabs(
        config,
        archive.keys()?,
        |keys| archive.get(keys),
        |piece| {
            mesh.append(&piece);
            Ok(())
        },
    )?;
    Ok(mesh)
}

/// What a store holds, for `depthmesh info`: its identity, last checkpoint,
/// blocks, records, the tracker's keyframes and free space, and file size.
pub fn info(path: &Path) -> Result<Value> {
    let (_, saved) = MapStore::open_with(path, false)?;
    let size = std::fs::metadata(path)
        .map_err(|e| Error::io(path, e))?
        .len();
    let voxels = saved.stored_blocks * crate::tsdf::BLOCK_VOXELS;
    let tracker = saved
        .session
        .poses
        .as_ref()
        .and_then(|p| p.tracker.as_ref());
    Ok(json!({
        "store": path.display().to_string(),
        "format": FORMAT,
        "map": saved.identity["map"],
        "frames": saved.session.map.frames(),
        "records": saved.session.records.len(),
        "dataset_position": saved.position,
        "blocks": saved.stored_blocks,
        "resident_blocks": saved.resident_blocks,
        "cells": match &saved.session.map {
            SavedMap::Planes { cells, .. } => Some(cells.len()),
            _ => None,
        },
        "triangles": match &saved.session.map {
            SavedMap::Mabdi(m) => Some(m.mesh.triangle_count()),
            _ => None,
        },
        "tracked": saved.session.poses.is_some(),
        "keyframes": tracker.map(|t| t.keyframe_poses.len()),
        "free_space_regions": tracker.is_some().then_some(saved.stored_regions),
        "voxels": voxels,
        "file_bytes": size,
        "file_bytes_per_voxel": (voxels > 0).then(|| size as f64 / voxels as f64),
        "identity": saved.identity,
    }))
}

/// Reads a whole store.
fn read_saved(db: &Database, path: &Path, decode: bool) -> Result<Saved> {
    let bad = |message: String| Error::format(path, message);
    let read = || -> std::result::Result<_, redb::Error> {
        let txn = db.begin_read()?;
        let meta = txn.open_table(META)?;
        let format = meta.get("format")?.map(|v| v.value().to_vec());
        let identity = meta.get("identity")?.map(|v| v.value().to_vec());
        let checkpoint = meta.get("checkpoint")?.map(|v| v.value().to_vec());
        let tracking = meta.get("tracking")?.map(|v| v.value().to_vec());
        let last_view = meta.get("last_view")?.map(|v| v.value().to_vec());
        let resident = meta.get("resident")?.map(|v| v.value().to_vec());
        let mabdi = meta.get("mabdi")?.map(|v| v.value().to_vec());
        let planes = meta.get("planes")?.map(|v| v.value().to_vec());
        let stored_blocks = txn.open_table(BLOCKS)?.len()? as usize;
        let mut records = Vec::new();
        for entry in txn.open_table(RECORDS)?.iter()? {
            let (_, v) = entry?;
            records.push(v.value().to_vec());
        }
        // Absent from stores made before the tracker's free space was kept.
        let mut free_space = Vec::new();
        let mut stored_regions = 0;
        match txn.open_table(FREE_SPACE) {
            Ok(table) => {
                stored_regions = table.len()? as usize;
                if decode {
                    for entry in table.iter()? {
                        let (k, v) = entry?;
                        free_space.push((k.value(), v.value().to_vec()));
                    }
                }
            }
            Err(redb::TableError::TableDoesNotExist(_)) => {}
            Err(e) => return Err(e.into()),
        }
        Ok((
            [
                format, identity, checkpoint, tracking, last_view, resident, mabdi, planes,
            ],
            [stored_blocks, stored_regions],
            records,
            free_space,
        ))
    };
    let (meta, [stored_blocks, stored_regions], records, free_space) =
        read().map_err(|e| store_error(path, e))?;
    let [format, identity, checkpoint, tracking, last_view, resident, mabdi, planes] = meta;
    let format = format
        .and_then(|f| <[u8; 8]>::try_from(f.as_slice()).ok())
        .map(u64::from_le_bytes)
        .ok_or_else(|| bad("not a depthmesh map store (no format)".into()))?;
    if format != FORMAT {
        return Err(bad(format!(
            "store format {format}; this depthmesh reads format {FORMAT}"
        )));
    }
    let json = |bytes: Option<Vec<u8>>, what: &str| -> Result<Value> {
        let bytes = bytes.ok_or_else(|| bad(format!("no {what}")))?;
        serde_json::from_slice(&bytes).map_err(|e| bad(format!("{what}: {e}")))
    };
    let identity = json(identity, "identity")?;
    let checkpoint = match checkpoint {
        Some(c) => json(Some(c), "checkpoint")?,
        None => json!({"frames": 0, "position": 0, "records": 0}),
    };
    let number = |k: &str| {
        checkpoint[k]
            .as_u64()
            .ok_or_else(|| bad(format!("checkpoint: no {k}")))
    };
    let frames = u32::try_from(number("frames")?).map_err(|_| bad("checkpoint: frames".into()))?;
    let position = number("position")? as usize;
    if number("records")? as usize != records.len() {
        return Err(bad("checkpoint and records disagree".into()));
    }
    let records = records
        .iter()
        .enumerate()
        .map(|(i, r)| records::decode(r).map_err(|e| bad(format!("record {i}: {e}"))))
        .collect::<Result<Vec<_>>>()?;
    let poses = match tracking {
        Some(t) => {
            let t = json(Some(t), "tracking")?;
            let mut poses = pose_state_from(&t).map_err(bad)?;
            if let Some(tracker) = poses.tracker.as_mut() {
                // Absent from stores saved before the tracker kept it:
                // their resumed runs verify against the space the frames
                // after the resume see.
                let frames = t["tracker"]["free_space_frames"].as_u64().unwrap_or(0);
                tracker.free_space = free_space_from(frames as usize, &free_space).map_err(bad)?;
            }
            Some(poses)
        }
        None => None,
    };
    let hashes = arrays::Hashes::default();
    // With bounded memory, the blocks that were in memory.
    let resident: Option<Vec<glam::IVec3>> = resident
        .map(|r| resident_keys(&r).map_err(|e| bad(format!("resident blocks: {e}"))))
        .transpose()?;
    let map = match identity["map"].as_str() {
        Some("tsdf") => {
            let last_view = last_view
                .map(|v| view_from(&v).map_err(|e| bad(format!("last view: {e}"))))
                .transpose()?;
            let blocks = if decode {
                let bytes =
                    block_bytes(db, resident.as_deref()).map_err(|e| store_error(path, e))?;
                decode_blocks(&identity, bytes).map_err(bad)?
            } else {
                Vec::new()
            };
            SavedMap::Tsdf {
                blocks,
                frames,
                last_view,
            }
        }
        // The map parts of the others are read in a second transaction
        // (nothing writes between: the store is held open by this process).
        Some("planes") => {
            let planes = match planes {
                Some(p) => json(Some(p), "planes")?,
                None => json!({"inserts": 0}),
            };
            let per_side = identity["cell"].as_f64().unwrap_or(0.0)
                / identity["voxel"].as_f64().unwrap_or(1.0);
            let voxels = (per_side.round() as usize).pow(3);
            let txn = db.begin_read().map_err(|e| store_error(path, e))?;
            SavedMap::Planes {
                cells: cells::read(&txn, voxels).map_err(bad)?,
                frames,
                inserts: planes["inserts"]
                    .as_u64()
                    .and_then(|i| u32::try_from(i).ok())
                    .ok_or_else(|| bad("planes: no inserts".into()))?,
            }
        }
        Some("mabdi") => match mabdi {
            Some(m) => {
                let txn = db.begin_read().map_err(|e| store_error(path, e))?;
                let meta = json(Some(m), "mabdi")?;
                SavedMap::Mabdi(arrays::read(&txn, &meta, &hashes).map_err(bad)?)
            }
            None => SavedMap::Mabdi(crate::mabdi::MabdiState {
                mesh: crate::mesh::Mesh::default(),
                iteration: 0,
                votes: Vec::new(),
                patches: Vec::new(),
                next_patch: 0,
            }),
        },
        other => return Err(bad(format!("identity: map {other:?}"))),
    };
    Ok(Saved {
        identity,
        position,
        session: Resumed {
            records,
            map,
            poses,
        },
        stored_blocks,
        stored_regions,
        resident_blocks: resident.map(|r| r.len()),
        hashes,
    })
}

/// The stored bytes of the blocks `keys`, or of every block.
fn block_bytes(
    db: &Database,
    keys: Option<&[glam::IVec3]>,
) -> std::result::Result<Vec<KeyedBytes>, redb::Error> {
    let txn = db.begin_read()?;
    let table = txn.open_table(BLOCKS)?;
    let mut blocks = Vec::new();
    match keys {
        Some(keys) => {
            for k in keys {
                let key = (k.x, k.y, k.z);
                if let Some(v) = table.get(key)? {
                    blocks.push((key, v.value().to_vec()));
                }
            }
        }
        None => {
            for entry in table.iter()? {
                let (k, v) = entry?;
                blocks.push((k.value(), v.value().to_vec()));
            }
        }
    }
    Ok(blocks)
}

/// An entry of a table keyed by integer coordinates, with its stored
/// bytes: a TSDF block's or a free-space region's.
type KeyedBytes = ((i32, i32, i32), Vec<u8>);

/// TSDF blocks from their stored bytes.
fn decode_blocks(
    identity: &Value,
    bytes: Vec<KeyedBytes>,
) -> std::result::Result<Vec<crate::tsdf::Block>, String> {
    let color = colour(identity);
    bytes
        .into_par_iter()
        .map(|((x, y, z), bytes)| {
            block_codec::decode(glam::IVec3::new(x, y, z), &bytes, color)
                .map_err(|e| format!("block ({x}, {y}, {z}): {e}"))
        })
        .collect()
}

/// Whether a store's blocks hold colours, by its identity.
fn colour(identity: &Value) -> bool {
    identity["color"].as_bool().unwrap_or(false)
}

/// The keys of a checkpoint's `resident` entry.
fn resident_keys(bytes: &[u8]) -> std::result::Result<Vec<glam::IVec3>, String> {
    let raw = lz4_flex::decompress_size_prepended(bytes).map_err(|e| e.to_string())?;
    if raw.len() % 12 != 0 {
        return Err(format!("{} bytes, not whole keys", raw.len()));
    }
    let i = |b: &[u8]| i32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    Ok(raw
        .chunks_exact(12)
        .map(|k| glam::IVec3::new(i(&k[..4]), i(&k[4..8]), i(&k[8..])))
        .collect())
}

/// The tracking state as JSON (poses as [`records::pose_array`]).
fn pose_state_json(p: &PoseState) -> Value {
    json!({
        "tracker": p.tracker.as_ref().map(|t| json!({
            "last_good": records::pose_array(&t.last_good),
            "velocity": records::pose_array(&t.velocity),
            "lost_streak": t.lost_streak,
            "since_good": t.since_good,
            "held_streak": t.held_streak,
            "velocity_known": t.velocity_known,
            "fine_first": t.fine_first,
            "last_conditioning": t.last_conditioning,
            "keyframe_codes": t.keyframe_codes,
            "keyframe_poses": t.keyframe_poses.iter().map(records::pose_array).collect::<Vec<_>>(),
            "free_space_frames": t.free_space.frames(),
        })),
        "lost": p.lost,
        "lost_frames": p.lost_frames,
        "streak": p.streak,
        "track_seconds": p.track_seconds,
        "tracked": p.tracked,
        "clock": {
            "last": p.clock.last,
            "interval": p.clock.interval,
            "gaps_in_a_row": p.clock.gaps_in_a_row,
            "own_interval": p.clock.own_interval,
            "passed": p.clock.passed,
        },
        "dropped_frames": p.dropped_frames,
    })
}

/// Entry `k` of `v` as a count; why not, naming it.
fn count(v: &Value, k: &str) -> std::result::Result<usize, String> {
    v[k].as_u64()
        .map(|n| n as usize)
        .ok_or_else(|| format!("tracking: no {k}"))
}

/// Entry `k` of `v` as a count, or `absent` when a state saved before it
/// was kept has none; present, it must be a count like the others.
fn count_or(v: &Value, k: &str, absent: usize) -> std::result::Result<usize, String> {
    match &v[k] {
        Value::Null => Ok(absent),
        _ => count(v, k),
    }
}

fn pose_state_from(v: &Value) -> std::result::Result<PoseState, String> {
    let tracker = match &v["tracker"] {
        Value::Null => None,
        t => Some(TrackerState {
            last_good: records::pose_from(&t["last_good"])?,
            velocity: records::pose_from(&t["velocity"])?,
            lost_streak: count(t, "lost_streak")?,
            // Absent from sessions saved before dropped frames were
            // counted: each frame since the last good one was one interval.
            since_good: count_or(t, "since_good", count(t, "lost_streak")?)?,
            // Absent from sessions saved before followed frames were held.
            held_streak: count_or(t, "held_streak", 0)?,
            velocity_known: t["velocity_known"]
                .as_bool()
                .ok_or("tracking: no velocity_known")?,
            // Absent from sessions saved before the tracker kept it: those
            // tried every frame against the coarse view first.
            fine_first: t["fine_first"].as_bool().unwrap_or(false),
            // Absent likewise: the first frame after it is aligned at full
            // resolution.
            last_conditioning: t["last_conditioning"].as_f64().unwrap_or(0.0),
            keyframe_codes: t["keyframe_codes"]
                .as_array()
                .ok_or("tracking: no keyframe codes")?
                .iter()
                .map(|c| {
                    c.as_u64()
                        .and_then(|c| u8::try_from(c).ok())
                        .ok_or("tracking: bad code")
                })
                .collect::<std::result::Result<_, _>>()?,
            keyframe_poses: t["keyframe_poses"]
                .as_array()
                .ok_or("tracking: no keyframe poses")?
                .iter()
                .map(records::pose_from)
                .collect::<std::result::Result<_, _>>()?,
            // Kept in an entry of its own ([`read_saved`]).
            free_space: FreeSpace::default(),
        }),
    };
    Ok(PoseState {
        tracker,
        lost: count(v, "lost")?,
        lost_frames: count(v, "lost_frames")?,
        streak: count(v, "streak")?,
        track_seconds: v["track_seconds"]
            .as_f64()
            .ok_or("tracking: no track_seconds")?,
        tracked: count(v, "tracked")?,
        clock: clock_from(&v["clock"])?,
        // Absent likewise: no frame was counted dropped.
        dropped_frames: count_or(v, "dropped_frames", 0)?,
    })
}

/// The frames' clock saved with the tracking state; a new one for
/// sessions saved before it was kept (their next frame counts as the
/// first).
fn clock_from(v: &Value) -> std::result::Result<FrameClock, String> {
    let time = |k: &str| match &v[k] {
        Value::Null => Ok(None),
        t => t
            .as_f64()
            .map(Some)
            .ok_or_else(|| format!("tracking: clock {k} {t} is not a number")),
    };
    Ok(FrameClock {
        last: time("last")?,
        interval: time("interval")?,
        gaps_in_a_row: count_or(v, "gaps_in_a_row", 0)?,
        own_interval: time("own_interval")?,
        passed: count_or(v, "passed", 0)?,
    })
}

/// The tracker's free space of `frames` frames from the store's regions
/// (their keys and LZ4-compressed bytes).
fn free_space_from(
    frames: usize,
    regions: &[KeyedBytes],
) -> std::result::Result<FreeSpace, String> {
    let raw = regions
        .iter()
        .map(|((x, y, z), bytes)| {
            lz4_flex::decompress_size_prepended(bytes)
                .map(|raw| (glam::IVec3::new(*x, *y, *z), raw))
                .map_err(|e| format!("free space region ({x}, {y}, {z}): {e}"))
        })
        .collect::<std::result::Result<Vec<_>, _>>()?;
    FreeSpace::decode(frames, raw.iter().map(|(k, b)| (*k, b.as_slice())))
}

/// The last fused view: pose (12 × f32), width and height (u32), then the
/// depth (f32 each) LZ4-compressed; little-endian.
fn view_bytes(pose: &Pose, depth: &DepthImage) -> Vec<u8> {
    let mut out = Vec::new();
    for x in records::pose_array(pose) {
        out.extend_from_slice(&x.to_le_bytes());
    }
    out.extend_from_slice(&depth.width.to_le_bytes());
    out.extend_from_slice(&depth.height.to_le_bytes());
    let raw: Vec<u8> = depth.data.iter().flat_map(|d| d.to_le_bytes()).collect();
    out.extend_from_slice(&lz4_flex::compress_prepend_size(&raw));
    out
}

fn view_from(bytes: &[u8]) -> std::result::Result<(Pose, DepthImage), String> {
    if bytes.len() < 56 {
        return Err("too short".into());
    }
    let f = |i: usize| f32::from_le_bytes(bytes[4 * i..4 * i + 4].try_into().expect("4 bytes"));
    let a: Vec<f32> = (0..12).map(f).collect();
    let pose = Pose::new(
        glam::Mat3::from_cols_slice(&a[..9]),
        glam::Vec3::new(a[9], a[10], a[11]),
    );
    let u = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"));
    let (width, height) = (u(48), u(52));
    let raw = lz4_flex::decompress_size_prepended(&bytes[56..]).map_err(|e| e.to_string())?;
    if raw.len() != 4 * width as usize * height as usize {
        return Err("depth size".into());
    }
    let data = raw
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    Ok((
        pose,
        DepthImage {
            width,
            height,
            data,
        },
    ))
}

/// Runs `f`, turning a panic into an error naming `path`: redb 4.6 checks
/// its pages' checksums, but some damaged files (overwritten pages) make it
/// panic while opening them rather than return an error. The panic message
/// is kept off the terminal; the error says what happened.
fn without_panics<T>(path: &Path, f: impl FnOnce() -> Result<T>) -> Result<T> {
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    std::panic::set_hook(hook);
    result.unwrap_or_else(|_| {
        Err(Error::format(
            path,
            "map store: damaged (its structure is inconsistent)",
        ))
    })
}

/// A store's error, naming the file and saying what to do.
fn store_error(path: &Path, e: impl Into<redb::Error>) -> Error {
    let e: redb::Error = e.into();
    let hint = match &e {
        redb::Error::Corrupted(_) | redb::Error::Io(_) => " (the file is damaged or not a store)",
        redb::Error::DatabaseAlreadyOpen => " (another process has it open)",
        _ => "",
    };
    Error::format(path, format!("map store: {e}{hint}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Pose;

    /// A tracked session's pose state as a run two frames after a gap
    /// holds it.
    fn state() -> PoseState {
        let mut tracker = TrackerState::moving(
            Pose::new(glam::Mat3::IDENTITY, glam::Vec3::new(1.0, 0.5, -2.0)),
            Pose::new(glam::Mat3::IDENTITY, glam::Vec3::new(0.01, 0.0, 0.0)),
        );
        tracker.lost_streak = 2;
        tracker.since_good = 7;
        tracker.held_streak = 1;
        PoseState {
            tracker: Some(tracker),
            lost: 1,
            lost_frames: 2,
            streak: 2,
            track_seconds: 0.25,
            tracked: 40,
            clock: FrameClock {
                last: Some(41.5),
                interval: Some(0.5),
                gaps_in_a_row: 3,
                own_interval: Some(0.25),
                passed: 2,
            },
            dropped_frames: 5,
        }
    }

    #[test]
    fn the_tracking_state_comes_back_with_its_clock() {
        let saved = pose_state_json(&state());
        assert_eq!(pose_state_from(&saved).unwrap(), state());
    }

    #[test]
    fn a_state_saved_before_the_clock_and_gaps_reads_with_one_frame_a_loss() {
        let mut saved = pose_state_json(&state());
        saved.as_object_mut().unwrap().remove("clock");
        saved.as_object_mut().unwrap().remove("dropped_frames");
        saved["tracker"]
            .as_object_mut()
            .unwrap()
            .remove("since_good");
        let back = pose_state_from(&saved).unwrap();
        assert_eq!(back.clock, FrameClock::default());
        assert_eq!(back.dropped_frames, 0);
        assert_eq!(back.tracker.unwrap().since_good, 2);
    }

    #[test]
    fn a_malformed_count_or_time_in_the_tracking_state_is_refused_by_name() {
        for (path, bad) in [
            (&["tracker", "held_streak"][..], json!("one")),
            (&["tracker", "since_good"][..], json!(-3)),
            (&["clock", "interval"][..], json!("fast")),
            (&["clock", "gaps_in_a_row"][..], json!(true)),
            (&["clock", "own_interval"][..], json!("slow")),
            (&["clock", "passed"][..], json!(-1)),
            (&["dropped_frames"][..], json!(1.5)),
        ] {
            let mut saved = pose_state_json(&state());
            let mut at = &mut saved;
            for key in path {
                at = &mut at[*key];
            }
            *at = bad;
            let e = pose_state_from(&saved).unwrap_err();
            let name = path.last().unwrap();
            assert!(e.contains(name), "{name}: {e}");
        }
    }
}
