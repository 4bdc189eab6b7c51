#!/usr/bin/env bash
# A MABDI run against Open3D's RaycastingScene (Embree) rendering E alone for
# the run's own final global mesh M, from the run's own poses, side by side on
# this machine: the median whole mapping iteration of the run (E with the
# removal evidence, missing returns, classification, meshing, removal,
# simplification: stats.csv's `ms`) against Open3D's median time for E of the
# final M, which is the largest M of the run. The simulated sensor's render of
# D, which a real sensor does in hardware, is shown apart. The two sides take
# turns, ROUNDS times (default 3), so that other work on a shared machine
# weighs on both alike; each round's ratio is printed and their median.
#
#   bench/mabdi_vs_open3d.sh                 # the noisy dynamic bunnies run
#   bench/mabdi_vs_open3d.sh --scene scenes/table.toml   # any simulate flags
#   ROUNDS=5 bench/mabdi_vs_open3d.sh
#
# Needs the reference tools beside the repository (../shared/tools, or set
# DEPTHMESH_SHARED to the folder holding tools/ and data/).
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/setup.sh
if [[ $# -eq 0 ]]; then
  bunny=$shared/data/stanford-bunny/stanford_bunny.ply
  [[ -f $bunny ]] || { echo "error: $bunny not found (set DEPTHMESH_SHARED)" >&2; exit 1; }
  set -- --scene scenes/bunnies.toml --bunny "$bunny" --noise zbuffer:0.002 --iterations 50 --dynamic
fi
rounds=${ROUNDS:-3}
ratios=()
for round in $(seq 1 "$rounds"); do
  ./target/release/depthmesh simulate "$@" --quiet --force --out "$work/run" >/dev/null
  # The simulated sensor: 640x480, 60 degrees vertical field of view.
  theirs=$("$PY" "$shared/tools/open3d_raycast.py" "$work/run/mesh.ply" "$work/run/trajectory.txt" \
    --fx 415.692 --cx 319.5 --cy 239.5 | tail -1)
  echo "round $round of $rounds"
  ratio=$(python3 - "$work/run/stats.csv" "$work/run/summary.json" "$theirs" <<'PY'
import csv, json, statistics, sys
rows = list(csv.DictReader(open(sys.argv[1])))
summary, theirs = json.load(open(sys.argv[2])), json.loads(sys.argv[3])
med = lambda k: statistics.median(float(r[k]) for r in rows)
out = sys.stderr
print(f"run: {summary['scene']}, {summary['frames']} iterations, noise {summary['noise']}; "
      f"final M {summary['triangles']} triangles ({100 * summary['elements_vs_naive']:.2f} % of the traditional method)", file=out)
print(f"depthmesh, median whole mapping iteration   {med('ms'):7.1f} ms (mean {statistics.mean(float(r['ms']) for r in rows):.1f})", file=out)
print(f"  (the simulated sensor's render of D, not in it: mean {1000 * summary['sensor_seconds'] / summary['frames']:.1f} ms)", file=out)
for k in ("render_ms", "absence_ms", "classify_ms", "removal_ms", "smooth_ms", "mesh_ms", "settle_ms"):
    if k in rows[0]:
        print(f"  median {k:<26}  {med(k):7.1f} ms", file=out)
print(f"Open3D RaycastingScene, E of the final M ({theirs['triangles']} triangles, {theirs['images']} poses)  {theirs['median_ms']:7.1f} ms", file=out)
ratio = theirs['median_ms'] / med('ms')
print(f"ratio (Open3D E / depthmesh whole mapping iteration): {ratio:.2f}x", file=out)
print(ratio)
PY
  )
  ratios+=("$ratio")
done
python3 -c 'import statistics, sys; r = [float(x) for x in sys.argv[1:]]; print("median ratio over %d rounds: %.2fx (rounds: %s)" % (len(r), statistics.median(r), ", ".join("%.2f" % x for x in r)))' "${ratios[@]}"
