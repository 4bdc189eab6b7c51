#!/usr/bin/env bash
# The 7-Scenes kitchen played backwards: frames END-1 down to START (every
# STRIDE-th), renumbered from 0, tracked from the first of them (frame
# END-1's pose) alone by depthmesh (`reconstruct --track`) and by Open3D's
# dense SLAM in the same run, as bench/track_starts.sh does. A path none of
# the tracker's settings was chosen on: every motion runs the other way,
# and the run starts from a frame no other bench starts from. Prints the
# frames lost by each, each one's trajectory error against the folder's
# poses (from the first pose; after rigid alignment), every frame scored,
# a frame depthmesh lost at its last good pose, and both speeds.
#
# Usage: bench/track_reversed.sh [START] [END] [STRIDE] [VOXEL]
#   (defaults 0, 300, 1, 0.01)
# Needs ../shared beside the repository (or DEPTHMESH_SHARED).
set -euo pipefail
cd "$(dirname "$0")/.."
start=${1:-0}
end=${2:-300}
stride=${3:-1}
voxel=${4:-0.01}
for value in "$start" "$end" "$stride"; do
  if [[ ! $value =~ ^[0-9]+$ ]]; then
    echo "error: START, END and STRIDE must be whole numbers, got \"$value\"" >&2
    exit 1
  fi
done
if ((stride == 0 || end - 1 - start < stride)); then
  echo "error: STRIDE must be at least 1, and START..END must hold two frames STRIDE apart; got $start..$end, stride $stride" >&2
  exit 1
fi
need_kitchen=1
source bench/setup.sh
folder=$work/reversed
frames_folder "$folder"
count=0
for ((frame = end - 1; frame >= start; frame -= stride)); do
  link_frame "$frame" "$count" "$folder"
  count=$((count + 1))
done
echo "kitchen frames $((end - 1)) down to $start, every ${stride}, first pose given, ${voxel} m voxels"
track_both "$folder" 0 "$count" "$voxel" run
report_both "" run
