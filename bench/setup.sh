# Sourced by the scripts that compare depthmesh with the reference tools:
# finds ../shared (or DEPTHMESH_SHARED, as an absolute path in `shared`) and
# the 7-Scenes kitchen frames (`data`; a script that needs them sets
# need_kitchen=1 first), sets up the reference Python (PY), builds depthmesh
# in release and makes a scratch folder (work) removed on exit; defines
# frames_folder and link_frame, for folders of links to kitchen frames,
# track_both, which tracks frames with depthmesh and Open3D and scores
# both trajectories, and report_both, which prints one line of that.
# Run from the repository root.
shared=$(realpath -m "${DEPTHMESH_SHARED:-../shared}")
data=$shared/data/7scenes-redkitchen
if [[ ! -x $shared/tools/setup-anchors.sh ]]; then
  echo "error: reference tools not found in $shared/tools (set DEPTHMESH_SHARED)" >&2
  exit 1
fi
if [[ ${need_kitchen:-0} == 1 && ! -d $data ]]; then
  echo "error: 7-Scenes frames not found in $data (set DEPTHMESH_SHARED)" >&2
  exit 1
fi
PY=$("$shared/tools/setup-anchors.sh")
cargo build --release --quiet
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# Makes folder $1 for links to kitchen frames, with the camera's intrinsics.
frames_folder() {
  mkdir "$1"
  cp "$data/camera-intrinsics.txt" "$1/" 2>/dev/null || true
}

# Links every file of kitchen frame $1 into folder $3 as frame $2.
link_frame() {
  local f
  for f in "$data"/frame-$(printf %06d "$1").*; do
    ln -s "$f" "$3/frame-$(printf %06d "$2").${f#*/frame-??????.}"
  done
}

# Tracks frames $2..$3-1 of folder $1 from the first pose with both tools,
# $4 m voxels, into folder $work/$5: depthmesh's run in ours/, Open3D's
# dense SLAM (8³ blocks, 4-voxel truncation, as depthmesh) alongside, and
# both trajectories with every frame posed (depthmesh's lost frames at the
# last good pose, as Open3D keeps them) in depthmesh.txt and open3d.txt.
# Sets ours_ate, theirs (Open3D's run) and theirs_ate: JSON lines.
track_both() {
  local out=$work/$5
  mkdir -p "$out"
  ./target/release/depthmesh reconstruct "$1" --frames "$2..$3" --voxel "$4" --track --quiet --out "$out/ours"
  python3 bench/fill_lost_poses.py "$out/ours/trajectory.txt" "$2" "$3" > "$out/depthmesh.txt"
  ours_ate=$("$PY" "$shared/tools/trajectory_error.py" "$out/depthmesh.txt" --frames-folder "$1" | tail -1)
  theirs=$("$PY" "$shared/tools/open3d_slam.py" "$1" --start "$2" --end "$3" --voxel "$4" \
    --block-resolution 8 --trunc-voxels 4 --trajectory "$out/open3d.txt" | tail -1)
  theirs_ate=$("$PY" "$shared/tools/trajectory_error.py" "$out/open3d.txt" --frames-folder "$1" | tail -1)
}

# Prints one line for the last track_both into folder $work/$2, headed $1:
# the frames, each tool's lost frames, ATE (after rigid alignment, and the
# largest error) and frames/s, and the ratio of the speeds.
report_both() {
  python3 - "$1" "$work/$2/ours/summary.json" "$ours_ate" "$theirs" "$theirs_ate" <<'PY'
import json, sys
ours = json.load(open(sys.argv[2])); ate = json.loads(sys.argv[3])
theirs = json.loads(sys.argv[4]); theirs_ate = json.loads(sys.argv[5])
print(f"{sys.argv[1]}{ours['frames']} frames | depthmesh lost {ours['lost_frames']}, "
      f"ATE {ate['ate_rmse_cm']:.2f} cm (aligned {ate['ate_rmse_aligned_cm']:.2f}, max {ate['max_cm']:.2f}), "
      f"{ours['fps']:.1f} frames/s | Open3D lost {theirs['lost']}, ATE {theirs_ate['ate_rmse_cm']:.2f} cm "
      f"(aligned {theirs_ate['ate_rmse_aligned_cm']:.2f}, max {theirs_ate['max_cm']:.2f}), "
      f"{theirs['fps']:.1f} frames/s | ratio {ours['fps'] / theirs['fps']:.2f}x")
PY
}
