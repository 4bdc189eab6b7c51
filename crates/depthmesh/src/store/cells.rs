//! Voxel-plane statistics in the store: the grid's cells in the `cells`
//! table, keyed by allocation order (so a continued grid allocates as the
//! saved one did, and meshes the same). A cell is the key (3 × `i32`) then
//! its voxels' count (`u32`), centroid (3 × `f64`) and scatter (6 × `f64`),
//! x fastest, LZ4-compressed; a checkpoint writes the cells changed since
//! the previous one.

use super::MapWrite;
use crate::planes::grid::SavedCell;
use crate::planes::{PlanesMapper, Sym3, VoxelStats};
use glam::{DVec3, IVec3};
use rayon::prelude::*;
use redb::{ReadableTable, TableDefinition};

/// Cells by allocation order.
pub(super) const CELLS: TableDefinition<u64, &[u8]> = TableDefinition::new("cells");

/// Bytes per voxel before compression.
const VOXEL_BYTES: usize = 4 + 9 * 8;

/// The cells of `planes` changed after grid insertion `since`, encoded,
/// and the write that stores them.
pub(super) fn write(planes: &PlanesMapper, since: u32) -> MapWrite {
    let cells: Vec<(u64, Vec<u8>)> = planes
        .grid()
        .cells_changed_after(since)
        .into_par_iter()
        .map(|(slot, key, voxels)| (slot as u64, encode(key, voxels)))
        .collect();
    let bytes: usize = cells.iter().map(|(_, b)| b.len()).sum();
    let meta = serde_json::json!({"inserts": planes.grid().inserts()}).to_string();
    MapWrite {
        frames: planes.frames(),
        units: cells.len(),
        bytes,
        write: Box::new(move |txn| {
            let mut table = txn.open_table(CELLS)?;
            for (slot, b) in &cells {
                table.insert(*slot, b.as_slice())?;
            }
            txn.open_table(super::META)?
                .insert("planes", meta.as_bytes())?;
            Ok(bytes)
        }),
    }
}

/// Every cell of a store, in allocation order; `voxels` per cell.
pub(super) fn read(txn: &redb::ReadTransaction, voxels: usize) -> Result<Vec<SavedCell>, String> {
    let table = txn.open_table(CELLS).map_err(|e| e.to_string())?;
    let mut cells = Vec::new();
    for (i, entry) in table.iter().map_err(|e| e.to_string())?.enumerate() {
        let (slot, bytes) = entry.map_err(|e| e.to_string())?;
        if slot.value() != i as u64 {
            return Err(format!("cell {i} is missing"));
        }
        cells.push(decode(bytes.value(), voxels).map_err(|e| format!("cell {i}: {e}"))?);
    }
    Ok(cells)
}

fn encode(key: IVec3, voxels: &[VoxelStats]) -> Vec<u8> {
    let mut raw = Vec::with_capacity(12 + voxels.len() * VOXEL_BYTES);
    for c in key.to_array() {
        raw.extend_from_slice(&c.to_le_bytes());
    }
    for s in voxels {
        raw.extend_from_slice(&s.count.to_le_bytes());
        let m = &s.scatter;
        for x in s
            .mean
            .to_array()
            .into_iter()
            .chain([m.xx, m.xy, m.xz, m.yy, m.yz, m.zz])
        {
            raw.extend_from_slice(&x.to_le_bytes());
        }
    }
    lz4_flex::compress_prepend_size(&raw)
}

fn decode(bytes: &[u8], voxels: usize) -> Result<SavedCell, String> {
    let raw = lz4_flex::decompress_size_prepended(bytes).map_err(|e| e.to_string())?;
    if raw.len() != 12 + voxels * VOXEL_BYTES {
        return Err(format!("{} bytes for {voxels} voxels", raw.len()));
    }
    let i = |o: usize| i32::from_le_bytes(raw[o..o + 4].try_into().expect("4 bytes"));
    let key = IVec3::new(i(0), i(4), i(8));
    let stats = raw[12..]
        .chunks_exact(VOXEL_BYTES)
        .map(|v| {
            let f = |k: usize| {
                f64::from_le_bytes(v[4 + 8 * k..12 + 8 * k].try_into().expect("8 bytes"))
            };
            VoxelStats {
                count: u32::from_le_bytes(v[..4].try_into().expect("4 bytes")),
                mean: DVec3::new(f(0), f(1), f(2)),
                scatter: Sym3 {
                    xx: f(3),
                    xy: f(4),
                    xz: f(5),
                    yy: f(6),
                    yz: f(7),
                    zz: f(8),
                },
            }
        })
        .collect();
    Ok((key, stats))
}
