//! `--max-memory`: the map's memory budget. Settings whose map cannot fit
//! are refused before the first frame, with the estimate and why; a run
//! whose map outgrows the budget stops there and writes what it has,
//! rather than being killed by the kernel with nothing written.

use anyhow::{bail, Result};
use clap::Args;
use depthmesh::session::{MapConfig, Session};
use depthmesh::tsdf::TsdfConfig;
use depthmesh::{DepthImage, Intrinsics};

/// Without /proc/meminfo, the budget when none is given.
const FALLBACK_BUDGET: u64 = 8 << 30;

/// The memory budget flag.
#[derive(Args, Debug, Clone, Default)]
pub struct MemoryArgs {
    /// Most memory the map may take, e.g. 4G, 512M or a number of bytes
    /// (default: half the machine's physical memory, or 8G if unknown).
    /// A run reaching it stops and writes what it has.
    #[arg(long, value_parser = parse_size)]
    pub max_memory: Option<u64>,
}

/// A size in bytes with an optional K, M, G or T suffix (powers of 1024).
fn parse_size(text: &str) -> Result<u64, String> {
    let t = text.trim();
    let (number, unit) = match t.char_indices().find(|(_, c)| c.is_ascii_alphabetic()) {
        Some((i, _)) => t.split_at(i),
        None => (t, ""),
    };
    let shift = match unit
        .trim_end_matches(['B', 'b', 'i'])
        .to_ascii_uppercase()
        .as_str()
    {
        "" => 0,
        "K" => 10,
        "M" => 20,
        "G" => 30,
        "T" => 40,
        _ => {
            return Err(format!(
                "\"{text}\": use a number with K, M, G or T (e.g. 4G)"
            ))
        }
    };
    match number.trim().parse::<f64>() {
        Ok(n) if n > 0.0 && n.is_finite() => Ok((n * (1u64 << shift) as f64) as u64),
        _ => Err(format!("\"{text}\" is not a positive size (e.g. 4G)")),
    }
}

/// Half of `MemTotal` in /proc/meminfo, if it can be read.
fn half_of_physical_memory() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024 / 2)
}

/// The median of a frame's measured depths, metres (`None` without any):
/// the distance a recorded sequence's surfaces are typically at.
pub fn median_depth(depth: &DepthImage) -> Option<f32> {
    let mut valid: Vec<f32> = depth.data.iter().copied().filter(|d| *d > 0.0).collect();
    if valid.is_empty() {
        return None;
    }
    let middle = valid.len() / 2;
    Some(*valid.select_nth_unstable_by(middle, f32::total_cmp).1)
}

/// Bytes as a person reads them.
pub fn human(bytes: f64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut value = bytes;
    let mut unit = 0;
    while value >= 1024.0 && unit + 1 < UNITS.len() {
        value /= 1024.0;
        unit += 1;
    }
    format!("{value:.1} {}", UNITS[unit])
}

impl MemoryArgs {
    /// The budget in bytes.
    pub fn budget(&self) -> u64 {
        self.max_memory
            .or_else(half_of_physical_memory)
            .unwrap_or(FALLBACK_BUDGET)
    }

    /// Refuses a map of `frames` frames from camera `k` that cannot fit
    /// (a TSDF map's size is estimated; the others' stay small), with
    /// surfaces about `depth` metres away (`None`: at the far limit, an
    /// upper bound).
    pub fn check_map(
        &self,
        map: &MapConfig,
        k: &Intrinsics,
        frames: usize,
        depth: Option<f32>,
    ) -> Result<()> {
        match map {
            MapConfig::Tsdf(t) => {
                let depth = depth.map_or(t.range.1, |d| d.clamp(t.range.0, t.range.1));
                self.check_tsdf(&t.config, k, depth, frames)
            }
            _ => Ok(()),
        }
    }

    /// Refuses a TSDF map whose estimated size (see
    /// [`TsdfConfig::estimate_bytes`]) is over the budget.
    fn check_tsdf(
        &self,
        config: &TsdfConfig,
        k: &Intrinsics,
        depth: f32,
        frames: usize,
    ) -> Result<()> {
        let estimate = config.estimate_bytes(k, depth, frames);
        let budget = self.budget();
        if estimate > budget as f64 {
            let hint = if config.voxel < 0.002 {
                format!(
                    " --voxel is in metres: {} is {} mm (1 cm is 0.01).",
                    config.voxel,
                    (f64::from(config.voxel) * 1e9).round() / 1e6
                )
            } else {
                String::new()
            };
            bail!(
                "invalid --voxel: {frames} frame(s) of {}×{} depth around {depth:.1} m \
                 in {} m voxels need about {} of voxels, over the --max-memory budget of {}.{hint} \
                 Use larger voxels, fewer frames, a smaller --depth-max, or raise --max-memory",
                k.width,
                k.height,
                config.voxel,
                human(estimate),
                human(budget as f64)
            );
        }
        Ok(())
    }

    /// A line saying the map has outgrown the budget, if it has.
    pub fn exceeded(&self, session: &Session) -> Option<String> {
        let bytes = session.backend().mapper().stats().bytes;
        let budget = self.budget();
        (bytes as u64 > budget).then(|| {
            format!(
                "the map holds {}, over the --max-memory budget of {}",
                human(bytes as f64),
                human(budget as f64)
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_with_units() {
        assert_eq!(parse_size("4G"), Ok(4 << 30));
        assert_eq!(parse_size("512MiB"), Ok(512 << 20));
        assert_eq!(parse_size("1000"), Ok(1000));
        assert_eq!(parse_size("1.5k"), Ok(1536));
        assert!(parse_size("0").is_err());
        assert!(parse_size("4X").is_err());
    }
}
