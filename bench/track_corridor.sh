#!/usr/bin/env bash
# Tracking down a corridor (bench/corridor_walk.py: a floor, a wall, a box
# and a post every 3 m), with Kinect noise into a TSDF map, from the first
# pose alone: the straight walk, and the walk there and back, which turns
# round in one frame halfway (70°; with BACK, 35° + atan(BACK)). Per walk
# and noise seed, the trajectory error
# against the true poses (from the first pose; after rigid alignment), the
# frames lost, how many of the frames were fused, and the time to track the
# slowest frame, each frame after a lost one (the search for the camera) and
# the frame after that (tracked with no measured motion).
#
# Usage: bench/track_corridor.sh [LENGTH] [SEEDS] [BACK]   (defaults 20, "0 1 2", 0.7)
set -euo pipefail
cd "$(dirname "$0")/.."
length=${1:-20}
seeds=${2:-0 1 2}
back=${3:-0.7}
cargo build --release --quiet
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
python3 bench/corridor_walk.py "$length" "$work" "$back"
frames=$(wc -l < "$work/straight.txt")
echo "corridor ${length} m, ${frames} frames at 10 cm, Kinect noise, TSDF map"
for walk in straight there-and-back; do
  for seed in $seeds; do
    out="$work/$walk-$seed"
    ./target/release/depthmesh simulate --scene "$work/corridor.toml" --map tsdf --track \
      --noise kinect --path "tum:$work/$walk.txt" --iterations "$frames" --seed "$seed" \
      --quiet --out "$out" > /dev/null
    python3 - "$out" "$walk" "$seed" <<'PY'
import csv, json, sys
s = json.load(open(f"{sys.argv[1]}/summary.json"))
rows = list(csv.DictReader(open(f"{sys.argv[1]}/stats.csv")))
slow = max(rows, key=lambda r: float(r["track_ms"] or 0))
# The frame a lost one is found at, and the next, which starts with no measured motion.
# A frame found last in the walk has no next one.
after = rows[2:] + [None]
searches = [f"{r['frame']}: {float(r['track_ms']):.0f} ms"
            + (f", then {float(n['track_ms']):.0f} ms" if n else "")
            for p, r, n in zip(rows, rows[1:], after) if p["lost"] == "1"]
print(f"{sys.argv[2]:15} seed {sys.argv[3]}: ATE {s['ate_rmse_cm']:.2f} cm (aligned {s['ate_rmse_aligned_cm']:.2f}), "
      f"lost {s['lost_frames']} frames in {s['lost']} events, fused {s['frames_fused']} of {s['frames']}; "
      f"tracking: slowest frame {slow['frame']} {float(slow['track_ms']):.0f} ms, "
      f"frames after a lost one [{', '.join(searches)}]")
PY
  done
done
