#!/usr/bin/env bash
# TSDF fusion of 7-Scenes frames with the given poses: depthmesh against
# Open3D's VoxelBlockGrid with the same voxel size, truncation and depth range,
# side by side on this machine: integration frames/s, full mesh extraction
# time, and how far the two meshes are from each other; then depthmesh alone
# re-meshing the changed blocks after every frame (median ms per frame).
#
# Usage: bench/tsdf_vs_open3d.sh [FRAMES_END] [VOXEL]     (defaults 100, 0.01)
# Needs ../shared beside the repository (or DEPTHMESH_SHARED).
set -euo pipefail
cd "$(dirname "$0")/.."
end=${1:-100}
voxel=${2:-0.01}
need_kitchen=1
source bench/setup.sh
./target/release/depthmesh reconstruct "$data" --frames "0..$end" --voxel "$voxel" --quiet --out "$work/ours"
./target/release/depthmesh reconstruct "$data" --frames "0..$end" --voxel "$voxel" --remesh-every 1 --quiet --out "$work/every"
theirs=$("$PY" "$shared/tools/open3d_tsdf.py" "$data" --end "$end" --voxel "$voxel" --out "$work/open3d.ply" | tail -1)
compare=$("$PY" "$shared/tools/mesh_compare.py" "$work/ours/mesh.ply" "$work/open3d.ply" --threshold "$voxel" | tail -1)
python3 - "$work/ours/summary.json" "$theirs" "$compare" "$work/every/stats.csv" <<'PY'
import csv, json, statistics, sys
ours = json.load(open(sys.argv[1])); theirs = json.loads(sys.argv[2]); cmp = json.loads(sys.argv[3])
print(f"frames {ours['frames']}, voxel {ours['voxel']:.3f} m, truncation {ours['truncation']:.3f} m")
print(f"integration   depthmesh {ours['integrate_fps']:6.1f} frames/s   Open3D {theirs['integrate_fps']:6.1f} frames/s   ratio {ours['integrate_fps'] / theirs['integrate_fps']:.2f}x")
print(f"mesh          depthmesh {ours['mesh_seconds']:6.3f} s          Open3D {theirs['mesh_seconds']:6.3f} s          ratio {theirs['mesh_seconds'] / ours['mesh_seconds']:.2f}x")
print(f"triangles     depthmesh {ours['triangles']}   Open3D {theirs['triangles']}")
print(f"memory        {ours['bytes_per_voxel']:.1f} bytes per voxel, {ours['blocks']} blocks")
rows = list(csv.DictReader(open(sys.argv[4])))[10:]  # after the first frames' allocation
med = lambda k: statistics.median(float(r[k]) for r in rows)
print(f"per frame     integrate {med('integrate_ms'):.1f} ms + re-mesh {med('remesh_ms'):.1f} ms of {med('remeshed_blocks'):.0f} blocks "
      f"= {1000 / (med('integrate_ms') + med('remesh_ms')):.1f} frames/s (--remesh-every 1, medians from frame 10)")
print(f"agreement     mean distance ours→Open3D {cmp['accuracy_mean']*1000:.2f} mm, Open3D→ours {cmp['completeness_mean']*1000:.2f} mm, F-score at one voxel {cmp['fscore']:.3f}")
PY
