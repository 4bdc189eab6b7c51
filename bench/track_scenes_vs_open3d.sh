#!/usr/bin/env bash
# Camera tracking on simulated scenes, depthmesh against Open3D's dense
# RGB-D SLAM on the same frames. For each scene and seed, `depthmesh
# simulate --track` (Kinect noise, TSDF map, only the first pose given)
# runs and saves the frames it took (`--save-frames`: depth in millimetres,
# true poses); Open3D then tracks those frames from the same first pose,
# with depthmesh's 8³ blocks and 4-voxel truncation. Its SLAM model always
# fuses colour, and the simulator has none: it is given mid-grey images,
# which its point-to-plane tracking does not use. Prints, per run, frames
# lost, the trajectory error against the true poses (RMS over every frame,
# a lost one at the last good pose; in brackets after rigid alignment) and
# frames per second (tracking and fusion; the simulator's rendering and
# reading the images not counted), and at the end the mean over the seeds
# per scene.
#
# Usage: bench/track_scenes_vs_open3d.sh [ITERATIONS] [SEEDS] [SCENES]
#   defaults: 200, "0 1 2", "table bunnies room open_space chairs sofa_room plane_and_box"
#   (a name from scenes/, or the path of a scene file ending in .toml)
# Needs ../shared beside the repository (or DEPTHMESH_SHARED).
set -euo pipefail
cd "$(dirname "$0")/.."
iterations=${1:-200}
seeds=${2:-0 1 2}
scenes=${3:-table bunnies room open_space chairs sofa_room plane_and_box}
source bench/setup.sh
bunny=$shared/data/stanford-bunny/stanford_bunny.ply
printf '%-14s %4s   %-36s   %-36s\n' scene seed "depthmesh ATE cm (aligned) lost fps" "Open3D ATE cm (aligned) lost fps"
for scene in $scenes; do
  file=scenes/$scene.toml
  [[ $scene == *.toml ]] && { file=$scene; scene=$(basename "$scene" .toml); }
  for seed in $seeds; do
    run=$work/$scene-$seed
    extra=()
    grep -qE '^[^#]*\$\{bunny\}' "$file" && extra=(--bunny "$bunny")
    ./target/release/depthmesh simulate --quiet --scene "$file" --map tsdf --track \
      --noise kinect --iterations "$iterations" --seed "$seed" --save-frames --out "$run" \
      "${extra[@]}" > /dev/null 2> "$run.log" || { cat "$run.log"; exit 1; }
    # Open3D reads `.color.jpg` beside each depth image.
    mkdir "$run/open3d-input"
    ln -s "$run"/frames/* "$run/open3d-input/"
    "$PY" - "$run/open3d-input" <<'PY'
import glob, sys
import numpy as np, open3d as o3d
grey = o3d.geometry.Image(np.full((480, 640, 3), 128, np.uint8))
for depth in glob.glob(f"{sys.argv[1]}/frame-*.depth.png"):
    o3d.io.write_image(depth.replace('.depth.png', '.color.jpg'), grey)
PY
    theirs=$("$PY" "$shared/tools/open3d_slam.py" "$run/open3d-input" --block-resolution 8 \
      --trunc-voxels 4 --trajectory "$run/open3d.txt" | tail -1)
    theirs_ate=$("$PY" "$shared/tools/trajectory_error.py" "$run/open3d.txt" \
      --frames-folder "$run/frames" | tail -1)
    python3 - "$scene" "$seed" "$run/summary.json" "$theirs" "$theirs_ate" <<'PY' | tee -a "$work/rows"
import json, sys
scene, seed = sys.argv[1], sys.argv[2]
ours = json.load(open(sys.argv[3]))
theirs, ate = json.loads(sys.argv[4]), json.loads(sys.argv[5])
a = f"{ours['ate_rmse_cm']:7.2f} ({ours['ate_rmse_aligned_cm']:6.2f}) {ours['lost_frames']:4d} {ours['fps']:6.1f}"
b = f"{ate['ate_rmse_cm']:7.2f} ({ate['ate_rmse_aligned_cm']:6.2f}) {theirs['lost']:4d} {theirs['fps']:6.1f}"
print(f"{scene:14s} {seed:>4s}   {a:36s}   {b:36s}")
PY
    rm -rf "$run"
  done
done
python3 - "$work/rows" <<'PY'
import sys
rows = {}
for line in open(sys.argv[1]):
    f = line.replace('(', ' ').replace(')', ' ').split()
    rows.setdefault(f[0], []).append([float(x) for x in f[2:10]])
print("mean over the seeds:")
for scene, r in rows.items():
    m = [sum(col) / len(r) for col in zip(*r)]
    print(f"{scene:14s}   depthmesh {m[0]:7.2f} ({m[1]:6.2f}) lost {m[2]:5.1f} {m[3]:6.1f} fps"
          f"   Open3D {m[4]:7.2f} ({m[5]:6.2f}) lost {m[6]:5.1f} {m[7]:6.1f} fps"
          f"   speed ratio {m[3] / m[7]:.2f}x")
PY
