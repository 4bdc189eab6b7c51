#!/usr/bin/env bash
# Simulated jumps: each scene's helix of ITERATIONS poses with frames
# A..B-1 left out, so the camera reappears 0.3-1.5 m from where it was last
# seen; tracked (`simulate --track --noise kinect --map tsdf`) per noise
# seed. MODE "dropped" keeps the helix's times, so the frames left out read
# as frames the sensor dropped while the camera moved on (the motion model
# spans the gap); "carried" numbers the poses anew, so the camera reads as
# carried off between two frames and must be searched for. Prints, per run, the jump, the times tracking was lost, the frames
# lost, the frames found again in the frame following lost them, the ATE
# over every frame (a lost one at its last good pose), and the share of the
# final map's surface within 2 cm of the scene: what frames fused at a
# wrong pose did to the map. Per scene and seed it first prints that share
# for the map fused at the true poses with the same noise, the share a
# tracked run's map is held to.
#
# Usage: bench/track_sim_jumps.sh [SCENES] [SEEDS] [GAPS] [MODE]
#   defaults "table bunnies room plane_and_box sofa_room chairs", "0 1",
#   "60:65 100:104 140:145" (A:B, frames A..B-1 left out), "dropped"
# Needs ../shared beside the repository (or DEPTHMESH_SHARED) for the bunny.
set -euo pipefail
cd "$(dirname "$0")/.."
scenes=${1:-table bunnies room plane_and_box sofa_room chairs}
seeds=${2:-0 1}
gaps=${3:-60:65 100:104 140:145}
mode=${4:-dropped}
if [[ $mode != dropped && $mode != carried ]]; then
  echo "error: MODE must be dropped or carried, got \"$mode\"" >&2
  exit 1
fi
iterations=200
shared=$(realpath -m "${DEPTHMESH_SHARED:-../shared}")
bunny=$shared/data/stanford-bunny/stanford_bunny.ply
cargo build --release --quiet
bin=./target/release/depthmesh
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
for scene in $scenes; do
  file=scenes/$scene.toml
  extra=()
  grep -qE '^[^#]*\$\{bunny\}' "$file" && extra=(--bunny "$bunny")
  # The helix's true poses, written by a tracked run as groundtruth.txt.
  rm -rf "$work/truth"
  $bin simulate --quiet --scene "$file" "${extra[@]}" --map tsdf --track \
    --iterations "$iterations" --out "$work/truth" > /dev/null
  # What the map's surface scores fused at the true poses with the same
  # noise: the share each tracked run's map is measured against.
  for seed in $seeds; do
    rm -rf "$work/fused"
    $bin simulate --quiet --scene "$file" "${extra[@]}" --map tsdf --noise kinect \
      --iterations "$iterations" --seed "$seed" --out "$work/fused" > /dev/null
    python3 - "$work/fused/summary.json" "$scene" "$seed" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
print(f"{sys.argv[2]:14s} fused at the true poses, every frame  seed {sys.argv[3]}: "
      f"map surface within 2 cm of the scene {100 * s['surface_within_2cm']:.1f} %")
PY
  done
  for gap in $gaps; do
    a=${gap%:*}
    b=${gap#*:}
    jump=$(python3 - "$work/truth/groundtruth.txt" "$a" "$b" "$work/path.txt" "$mode" <<'PY'
import math, sys
rows = [l for l in open(sys.argv[1]) if l.strip() and not l.startswith('#')]
a, b = int(sys.argv[2]), int(sys.argv[3])
kept = [r for i, r in enumerate(rows) if i < a or i >= b]
if sys.argv[5] == 'carried':
    kept = [f"{i + 1} {r.split(maxsplit=1)[1]}" for i, r in enumerate(kept)]
open(sys.argv[4], 'w').write(''.join(kept))
pa, pb = ([float(x) for x in rows[i].split()[1:4]] for i in (a - 1, b))
print(f"{math.dist(pa, pb):.2f}")
PY
)
    poses=$(grep -c . "$work/path.txt")
    for seed in $seeds; do
      rm -rf "$work/run"
      $bin simulate --quiet --scene "$file" "${extra[@]}" --map tsdf --track --noise kinect \
        --path "tum:$work/path.txt" --iterations "$poses" --seed "$seed" --out "$work/run" > /dev/null 2>&1 || true
      python3 - "$work/run/summary.json" "$scene" "$a" "$b" "$jump" "$seed" <<'PY'
import json, sys
scene, a, b, jump, seed = sys.argv[2:]
try:
    s = json.load(open(sys.argv[1]))
except OSError:
    print(f"{scene:14s} frames {a}..{int(b) - 1} left out ({jump} m)  seed {seed}: run failed")
    sys.exit()
print(f"{scene:14s} frames {a}..{int(b) - 1} left out ({jump} m)  seed {seed}: "
      f"lost {s['lost']} times, {s['lost_frames']} frames; found in the frame {s['recovered_frames']}; "
      f"ATE {s['ate_rmse_cm']:.2f} cm; map surface within 2 cm of the scene "
      f"{100 * s['surface_within_2cm']:.1f} %")
PY
    done
  done
done
