#!/usr/bin/env bash
# Camera tracking on 7-Scenes frames, only the first pose given: depthmesh
# (`reconstruct --track`, frame-to-model ICP + TSDF fusion) against Open3D's
# dense RGB-D SLAM (frame-to-model ICP + VoxelBlockGrid with depthmesh's 8³
# blocks and 4-voxel truncation; it always fuses colour too, which depthmesh
# does not), side by side on this machine: frames/s of tracking plus
# integration, lost frames, and the trajectory error against the folder's
# poses (no alignment, both starting at the first pose). A lost frame counts
# in the error at the last good pose, for both tools: Open3D keeps it there,
# and depthmesh's trajectory, which leaves lost frames out, is filled in so.
# The folder's poses are KinectFusion's own estimates, so
# the run ends with a reference-free comparison of the three trajectories:
# how well each registers the depth frames to each other
# (bench/trajectory_consistency.py, lower is better).
#
# With STRIDE > 1, both track every STRIDE-th frame of 0..FRAMES_END (a
# folder of links renumbered 0, 1, 2, …, with their poses): a camera moving
# STRIDE times faster, or a sensor dropping frames.
#
# Usage: bench/track_vs_open3d.sh [FRAMES_END] [VOXEL] [STRIDE]   (defaults 300, 0.01, 1)
# Needs ../shared beside the repository (or DEPTHMESH_SHARED).
set -euo pipefail
cd "$(dirname "$0")/.."
end=${1:-300}
voxel=${2:-0.01}
stride=${3:-1}
if [[ ! $stride =~ ^[1-9][0-9]*$ ]]; then
  echo "error: STRIDE must be a positive whole number, got \"$stride\"" >&2
  exit 1
fi
need_kitchen=1
source bench/setup.sh
if ((stride > 1)); then
  frames_folder "$work/strided"
  count=0
  for ((i = 0; i < end; i += stride)); do
    link_frame "$i" "$count" "$work/strided"
    count=$((count + 1))
  done
  echo "one frame in $stride of 0..$end: $count frames"
  data=$work/strided
  end=$count
fi
track_both "$data" 0 "$end" "$voxel" all
python3 - "$work/all/ours/summary.json" "$ours_ate" "$theirs" "$theirs_ate" <<'PY'
import json, sys
ours = json.load(open(sys.argv[1])); ate = json.loads(sys.argv[2])
theirs = json.loads(sys.argv[3]); theirs_ate = json.loads(sys.argv[4])
print(f"frames {ours['frames']}, voxel {ours['voxel']:.3f} m")
print(f"Open3D: {theirs['block_resolution']}³ blocks, truncation {theirs['trunc_voxels']} voxels, fuses colour as well as depth")
print(f"speed    depthmesh {ours['fps']:6.1f} frames/s ({ours['track_ms']:.1f} ms tracking per frame)   Open3D {theirs['fps']:6.1f} frames/s   ratio {ours['fps'] / theirs['fps']:.2f}x")
print(f"lost     depthmesh {ours['lost_frames']} frames ({ours['lost']} events)   Open3D {theirs['lost']} frames")
print(f"matched  depthmesh {ate['matched']} poses   Open3D {theirs_ate['matched']} poses   of {ours['frames']} frames (lost ones at the last good pose)")
print(f"ATE      depthmesh {ate['ate_rmse_cm']:.2f} cm (aligned {ate['ate_rmse_aligned_cm']:.2f}, max {ate['max_cm']:.2f})   "
      f"Open3D {theirs_ate['ate_rmse_cm']:.2f} cm (aligned {theirs_ate['ate_rmse_aligned_cm']:.2f}, max {theirs_ate['max_cm']:.2f})")
PY
"$PY" bench/trajectory_consistency.py "$data" "$work/all/depthmesh.txt" "$work/all/open3d.txt" folder --frames "$end"
