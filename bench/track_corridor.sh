#!/usr/bin/env bash
# Tracking down a corridor (bench/corridor_walk.py: a floor, a wall, a box
# and a post every 3 m), with Kinect noise into a TSDF map, from the first
# pose alone: the straight walk, and the walk there and back, which turns
# round in one frame halfway. Per walk and noise seed, the trajectory error
# against the true poses (from the first pose; after rigid alignment), the
# frames lost and how many of the frames were fused.
#
# Usage: bench/track_corridor.sh [LENGTH] [SEEDS]     (defaults 20, "0 1 2")
set -euo pipefail
cd "$(dirname "$0")/.."
length=${1:-20}
seeds=${2:-0 1 2}
cargo build --release --quiet
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
python3 bench/corridor_walk.py "$length" "$work"
frames=$(wc -l < "$work/straight.txt")
echo "corridor ${length} m, ${frames} frames at 10 cm, Kinect noise, TSDF map"
for walk in straight there-and-back; do
  for seed in $seeds; do
    out="$work/$walk-$seed"
    ./target/release/depthmesh simulate --scene "$work/corridor.toml" --map tsdf --track \
      --noise kinect --path "tum:$work/$walk.txt" --iterations "$frames" --seed "$seed" \
      --quiet --out "$out" > /dev/null
    python3 - "$out/summary.json" "$walk" "$seed" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
print(f"{sys.argv[2]:15} seed {sys.argv[3]}: ATE {s['ate_rmse_cm']:.2f} cm (aligned {s['ate_rmse_aligned_cm']:.2f}), "
      f"lost {s['lost_frames']} frames in {s['lost']} events, fused {s['frames_fused']} of {s['frames']}")
PY
  done
done
