#!/usr/bin/env bash
# Tracking on scenes none of its tuning saw: COUNT scenes of each kind the
# tracking table is judged on (table, room, bunnies, and clutter on a
# floor), drawn by bench/random_scene.py, each tracked per noise seed by
# depthmesh and by Open3D's dense SLAM on the same frames
# (bench/track_scenes_vs_open3d.sh, which prints every run). Ends with,
# per tool, over all runs: frames lost, the runs over 1 cm of ATE, and the
# median and largest ATE (from the first pose; after rigid alignment).
#
# Usage: bench/track_random_scenes.sh [COUNT] [SEEDS] [ITERATIONS]   (defaults 4, "0 1 2", 200)
# Needs ../shared beside the repository (or DEPTHMESH_SHARED).
set -euo pipefail
cd "$(dirname "$0")/.."
count=${1:-4}
seeds=${2:-0 1 2}
iterations=${3:-200}
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
scenes=()
for kind in table room bunnies clutter; do
  for n in $(seq 1 "$count"); do
    python3 bench/random_scene.py "$kind" "$n" > "$dir/$kind-$n.toml"
    scenes+=("$dir/$kind-$n.toml")
  done
done
bench/track_scenes_vs_open3d.sh "$iterations" "$seeds" "${scenes[*]}" | tee "$dir/runs"
python3 - "$dir/runs" <<'PY'
import statistics, sys
runs = []
for line in open(sys.argv[1]):
    f = line.replace('(', ' ').replace(')', ' ').split()
    if len(f) == 10 and f[1].isdigit():
        runs.append([float(x) for x in f[2:]])
print(f"over {len(runs)} runs:")
for name, c in (("depthmesh", 0), ("Open3D", 4)):
    ate = [r[c] for r in runs]
    aligned = [r[c + 1] for r in runs]
    print(f"{name:9s}  frames lost {sum(r[c + 2] for r in runs):.0f}"
          f"   runs over 1 cm {sum(a > 1.0 for a in ate)}"
          f"   ATE median {statistics.median(ate):.2f} cm, largest {max(ate):.2f}"
          f"   (aligned: median {statistics.median(aligned):.2f}, largest {max(aligned):.2f})")
PY
