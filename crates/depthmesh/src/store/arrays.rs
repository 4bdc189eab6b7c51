//! A MABDI map in the store: M's arrays (vertex positions and colours,
//! triangles, removal votes) cut into chunks of [`CHUNK`] bytes in the
//! `arrays` table, keyed by array name and chunk number, LZ4-compressed;
//! M's patches and iteration in the `mabdi` meta entry (JSON).
//!
//! M mostly grows at its end, and removal and simplification rewrite it from
//! some triangle on, so a checkpoint writes only the chunks whose bytes
//! changed since the previous one: it copies M on the frame thread and
//! compares chunk hashes, compresses and writes on the commit's thread.

use super::MapWrite;
use crate::mabdi::{MabdiMapper, MabdiState};
use crate::mesh::Mesh;
use glam::Vec3;
use redb::TableDefinition;
use serde_json::{json, Value};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// Chunks of M's arrays by (array, chunk number).
pub(super) const ARRAYS: TableDefinition<(&str, u64), &[u8]> = TableDefinition::new("arrays");

/// Bytes per chunk before compression.
const CHUNK: usize = 1 << 20;

/// The arrays, in the order they are written.
const NAMES: [&str; 4] = ["positions", "colors", "triangles", "votes"];

/// The hash of every chunk the store holds, by (array, chunk number).
pub(super) type Hashes = Arc<Mutex<HashMap<(&'static str, u64), u64>>>;

/// The write of `mabdi`'s state; `hashes` are the stored chunks' (kept up
/// to date by the write).
pub(super) fn write(mabdi: &MabdiMapper, hashes: Hashes) -> MapWrite {
    let state = mabdi.state();
    let frames = state.iteration;
    let m = &state.mesh;
    let bytes = 15 * m.positions.len() + 12 * m.triangles.len() + state.votes.len();
    MapWrite {
        frames,
        units: 0,
        bytes,
        write: Box::new(move |txn| {
            let mut table = txn.open_table(ARRAYS)?;
            let mut hashes = hashes.lock().unwrap_or_else(|e| e.into_inner());
            let arrays = arrays(&state);
            let mut written = 0;
            for (name, data) in NAMES.iter().zip(&arrays) {
                let chunks = data.len().div_ceil(CHUNK) as u64;
                for (i, chunk) in data.chunks(CHUNK).enumerate() {
                    let key = (*name, i as u64);
                    let h = hash(chunk);
                    if hashes.get(&key) != Some(&h) {
                        let compressed = lz4_flex::compress_prepend_size(chunk);
                        written += compressed.len();
                        table.insert(key, compressed.as_slice())?;
                        hashes.insert(key, h);
                    }
                }
                // The array shrank: its chunks past the end go.
                let stale: Vec<u64> = hashes
                    .keys()
                    .filter(|(n, i)| n == name && *i >= chunks)
                    .map(|(_, i)| *i)
                    .collect();
                for i in stale {
                    table.remove((*name, i))?;
                    hashes.remove(&(*name, i));
                }
            }
            drop(table);
            let meta = json!({
                "iteration": state.iteration,
                "next_patch": state.next_patch,
                "patches": state.patches,
                "lengths": NAMES.iter().zip(&arrays).map(|(n, a)| (n.to_string(), json!(a.len()))).collect::<serde_json::Map<_, _>>(),
            })
            .to_string();
            txn.open_table(super::META)?
                .insert("mabdi", meta.as_bytes())?;
            Ok(written)
        }),
    }
}

/// A saved MABDI state from the `mabdi` meta entry and the chunks; the
/// chunks' hashes are noted in `hashes`.
pub(super) fn read(
    txn: &redb::ReadTransaction,
    meta: &Value,
    hashes: &Hashes,
) -> Result<MabdiState, String> {
    let table = txn.open_table(ARRAYS).map_err(|e| e.to_string())?;
    let mut hashes = hashes.lock().unwrap_or_else(|e| e.into_inner());
    let mut arrays: Vec<Vec<u8>> = Vec::new();
    for name in NAMES {
        let length = meta["lengths"][name]
            .as_u64()
            .ok_or(format!("mabdi: no length of {name}"))? as usize;
        let mut data = Vec::with_capacity(length);
        for entry in table
            .range((name, 0)..=(name, u64::MAX))
            .map_err(|e| e.to_string())?
        {
            let (key, bytes) = entry.map_err(|e| e.to_string())?;
            let i = key.value().1;
            if i as usize * CHUNK != data.len() {
                return Err(format!("{name}: chunk {i} out of place"));
            }
            let chunk = lz4_flex::decompress_size_prepended(bytes.value())
                .map_err(|e| format!("{name} chunk {i}: {e}"))?;
            hashes.insert((name, i), hash(&chunk));
            data.extend_from_slice(&chunk);
        }
        if data.len() != length {
            return Err(format!("{name}: {} bytes, expected {length}", data.len()));
        }
        arrays.push(data);
    }
    let [positions, colors, triangles, votes] =
        <[Vec<u8>; 4]>::try_from(arrays).map_err(|_| "mabdi: arrays".to_string())?;
    let f32s = |b: &[u8]| -> Vec<f32> {
        b.chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect()
    };
    let mesh = Mesh {
        positions: f32s(&positions)
            .chunks_exact(3)
            .map(Vec3::from_slice)
            .collect(),
        colors: colors.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        triangles: triangles
            .chunks_exact(12)
            .map(|t| {
                let u = |o: usize| u32::from_le_bytes(t[o..o + 4].try_into().expect("4 bytes"));
                [u(0), u(4), u(8)]
            })
            .collect(),
        ..Mesh::default()
    };
    let number = |k: &str| meta[k].as_u64().ok_or(format!("mabdi: no {k}"));
    Ok(MabdiState {
        mesh,
        iteration: u32::try_from(number("iteration")?).map_err(|e| e.to_string())?,
        votes,
        patches: serde_json::from_value(meta["patches"].clone())
            .map_err(|e| format!("mabdi patches: {e}"))?,
        next_patch: u32::try_from(number("next_patch")?).map_err(|e| e.to_string())?,
    })
}

/// M's arrays as little-endian bytes, in [`NAMES`] order.
fn arrays(state: &MabdiState) -> [Vec<u8>; 4] {
    let m = &state.mesh;
    [
        m.positions
            .iter()
            .flat_map(|p| p.to_array())
            .flat_map(f32::to_le_bytes)
            .collect(),
        m.colors.iter().flatten().copied().collect(),
        m.triangles
            .iter()
            .flatten()
            .flat_map(|v| v.to_le_bytes())
            .collect(),
        state.votes.clone(),
    ]
}

/// A 64-bit hash of a chunk, eight bytes at a time (chunks that differ
/// collide with a chance of about 2⁻⁶⁴).
fn hash(bytes: &[u8]) -> u64 {
    let mut h = bytes.len() as u64;
    let mut words = bytes.chunks_exact(8);
    for w in &mut words {
        let w = u64::from_le_bytes(w.try_into().expect("8 bytes"));
        h = (h.rotate_left(5) ^ w).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    for &b in words.remainder() {
        h = (h.rotate_left(5) ^ u64::from(b)).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    h
}
