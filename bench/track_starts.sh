#!/usr/bin/env bash
# Tracking the 7-Scenes kitchen from other first frames: for each START,
# frames START..END-1 tracked from START's pose alone, by depthmesh
# (`reconstruct --track`) and by Open3D's dense SLAM (as in
# bench/track_vs_open3d.sh: 8³ blocks, 4-voxel truncation, colour fused
# too) in the same run. Per start: frames lost by each, and each one's
# trajectory error against the folder's poses (from the first pose; after
# rigid alignment), every frame scored, a frame depthmesh lost at its last
# good pose. A run that starts mid-sequence meets the scene as a held-out
# stretch would: no map yet, and no motion measured.
#
# Usage: bench/track_starts.sh [STARTS] [END] [VOXEL]   (defaults "25 50 100 150 200 250", 300, 0.01)
# Needs ../shared beside the repository (or DEPTHMESH_SHARED).
set -euo pipefail
cd "$(dirname "$0")/.."
starts=${1:-25 50 100 150 200 250}
end=${2:-300}
voxel=${3:-0.01}
for start in $starts; do
  if [[ ! $start =~ ^[0-9]+$ ]] || ((start + 1 >= end)); then
    echo "error: each START must be a whole number at least 2 frames before END ($end), got \"$start\"" >&2
    exit 1
  fi
done
need_kitchen=1
source bench/setup.sh
echo "kitchen frames START..$((end - 1)), first pose given, ${voxel} m voxels"
for start in $starts; do
  track_both "$data" "$start" "$end" "$voxel" "start-$start"
  report_both "$(printf 'start %4d: ' "$start")" "start-$start"
done
