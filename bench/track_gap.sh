#!/usr/bin/env bash
# Tracking through a jump on 7-Scenes: the frames of a gap are left out (a
# folder of links to the other frames, numbers kept), so the camera
# reappears 0.5-1 m from where it was last seen. Prints how far the camera
# jumped, the frames lost after the gap (the tracker searches near its last
# pose, then relocalises by global registration against the map and from
# its keyframes), and the whole trajectory's error against the folder's
# poses (only the first pose given; also after rigid alignment). Then the
# relocalisation alone: map from the frames before the gap, every query
# frame relocalised with no prior (`depthmesh eval relocalise`, one line
# per query frame with DEPTHMESH_VERBOSE=1).
#
# Usage: bench/track_gap.sh [BEFORE_END] [AFTER_START] [END]   (defaults 150 220 300)
# Needs ../shared beside the repository (or DEPTHMESH_SHARED).
set -euo pipefail
cd "$(dirname "$0")/.."
before=${1:-150}
after=${2:-220}
end=${3:-300}
need_kitchen=1
source bench/setup.sh
frames_folder "$work/frames"
for ((i = 0; i < end; i++)); do
  if ((i < before || i >= after)); then
    link_frame "$i" "$i" "$work/frames"
  fi
done
"$PY" - "$data" "$((before - 1))" "$after" <<'PY'
import sys, numpy as np
d, a, b = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
pa, pb = (np.loadtxt(f"{d}/frame-{i:06d}.pose.txt") for i in (a, b))
r = pa[:3, :3].T @ pb[:3, :3]
deg = np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))
print(f"gap      frames {a + 1}..{b} dropped: the camera moves {np.linalg.norm(pa[:3, 3] - pb[:3, 3]):.2f} m and {deg:.0f} deg")
PY
./target/release/depthmesh reconstruct "$work/frames" --track --quiet --out "$work/run" 2> "$work/log" || { cat "$work/log"; exit 1; }
grep -E "lost|recovered" "$work/log" | head -5 || true
ate=$("$PY" "$shared/tools/trajectory_error.py" "$work/run/trajectory.txt" --frames-folder "$data" | tail -1)
python3 - "$work/run/summary.json" "$ate" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); ate = json.loads(sys.argv[2])
print(f"tracked  {s['frames']} frames, {s['lost_frames']} lost ({s['lost']} events), "
      f"ATE {ate['ate_rmse_cm']:.2f} cm (max {ate['max_cm']:.2f}, after rigid alignment {ate['ate_rmse_aligned_cm']:.2f})")
PY
echo "relocalise: map 0..$before, queries $before..$end every 5th"
verbose=()
[[ ${DEPTHMESH_VERBOSE:-0} == 1 ]] && verbose=(--verbose)
./target/release/depthmesh eval relocalise "$data" --map-frames "0..$before" --query-frames "$before..$end" --stride 5 "${verbose[@]}"
