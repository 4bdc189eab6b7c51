//! A TSDF block as stored: its distances and weights (and colours) as
//! little-endian bytes, LZ4-compressed. Blocks are mostly truncated free
//! space (+1 everywhere) and low weights, which LZ4 shrinks several times
//! over at gigabytes a second, so a checkpoint stays cheap.

use crate::tsdf::{Block, BLOCK_VOXELS};
use glam::IVec3;

/// Writes `block` into `out` (cleared first).
pub fn encode(block: &Block, out: &mut Vec<u8>) {
    let mut raw = Vec::with_capacity(BLOCK_VOXELS * 7);
    for t in block.tsdf.iter() {
        raw.extend_from_slice(&t.to_le_bytes());
    }
    for w in block.weight.iter() {
        raw.extend_from_slice(&w.to_le_bytes());
    }
    if let Some(color) = &block.color {
        raw.extend(color.iter().flatten());
    }
    out.clear();
    out.extend_from_slice(&lz4_flex::compress_prepend_size(&raw));
}

/// The block with key `key` from `bytes`; `color` says whether it holds
/// colours. Anything but the exact size is an error.
pub fn decode(key: IVec3, bytes: &[u8], color: bool) -> Result<Block, String> {
    let raw = lz4_flex::decompress_size_prepended(bytes).map_err(|e| e.to_string())?;
    let expected = BLOCK_VOXELS * (4 + if color { 3 } else { 0 });
    if raw.len() != expected {
        return Err(format!("{} bytes, expected {expected}", raw.len()));
    }
    let mut tsdf = Box::new([0i16; BLOCK_VOXELS]);
    let mut weight = Box::new([0u16; BLOCK_VOXELS]);
    let (t, rest) = raw.split_at(2 * BLOCK_VOXELS);
    let (w, c) = rest.split_at(2 * BLOCK_VOXELS);
    for (v, b) in tsdf.iter_mut().zip(t.chunks_exact(2)) {
        *v = i16::from_le_bytes([b[0], b[1]]);
    }
    for (v, b) in weight.iter_mut().zip(w.chunks_exact(2)) {
        *v = u16::from_le_bytes([b[0], b[1]]);
    }
    let color = color.then(|| {
        let mut out = Box::new([[0u8; 3]; BLOCK_VOXELS]);
        for (v, b) in out.iter_mut().zip(c.chunks_exact(3)) {
            *v = [b[0], b[1], b[2]];
        }
        out
    });
    Ok(Block {
        key,
        tsdf,
        weight,
        color,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_block_comes_back_exactly_and_damage_is_refused() {
        let mut block = Block {
            key: IVec3::new(-3, 4, 5),
            tsdf: Box::new([32767; BLOCK_VOXELS]),
            weight: Box::new([0; BLOCK_VOXELS]),
            color: Some(Box::new([[0; 3]; BLOCK_VOXELS])),
        };
        for i in 0..BLOCK_VOXELS {
            block.tsdf[i] = (i as i16).wrapping_mul(97);
            block.weight[i] = (i % 7) as u16;
            block.color.as_mut().unwrap()[i] = [i as u8, 2, 3];
        }
        let mut bytes = Vec::new();
        encode(&block, &mut bytes);
        let back = decode(block.key, &bytes, true).unwrap();
        assert_eq!(back.tsdf, block.tsdf);
        assert_eq!(back.weight, block.weight);
        assert_eq!(back.color, block.color);
        assert!(decode(block.key, &bytes, false).is_err(), "colour mismatch");
        assert!(
            decode(block.key, &bytes[..bytes.len() / 2], true).is_err(),
            "truncated"
        );
    }
}
