#!/usr/bin/env bash
# Tracking on a live service that drops frames: one `stream --track` client
# sends FRAMES 7-Scenes kitchen frames to `depthmesh serve` (TSDF, 1 cm) as
# a live sensor at each rate of RATES (--realtime: the server maps the
# newest frame and drops what it cannot keep up with), or as fast as the
# server maps every frame ("max", no --realtime: nothing dropped). The
# server tells the tracker the times of the frames it drops, which it
# predicts across. Prints per run: frames sent, mapped and dropped by the
# server, the frames the run counted as dropped by the sensor (never sent;
# none from a folder without gaps), frames lost, and the ATE
# against the folder's poses over the frames mapped and over every frame
# sent (a dropped or lost frame at the last pose mapped before it, as a
# live map would show it).
#
# Usage: bench/serve_track_drops.sh [FRAMES] [RATES]   (defaults 300, "max 30 60 90")
# Needs ../shared beside the repository (or DEPTHMESH_SHARED): the kitchen
# and the trajectory metric. Loopback only; every run is bounded in time.
set -euo pipefail
cd "$(dirname "$0")/.."
frames=${1:-300}
rates=${2:-max 30 60 90}
source bench/serve_common.sh
PY=$("$shared/tools/setup-anchors.sh")
ate() {
  "$PY" "$shared/tools/trajectory_error.py" "$1" --frames-folder "$data" | tail -1
}
printf '%-5s %5s %7s %8s %16s %5s %26s %26s\n' rate sent mapped dropped "sensor dropped" lost \
  "ATE mapped, cm (aligned)" "ATE every frame (aligned)"
for rate in $rates; do
  mode=(--rate "$rate" --realtime)
  [[ $rate == max ]] && mode=(--rate max)
  start_server --map tsdf --voxel 0.01 --out "$work/server-$rate"
  timeout $((frames / 10 + 120)) "$bin" stream "$data" --server "$url" --token bench \
    --frames "0..$frames" --track "${mode[@]}" --session "run" --quiet --out "$work/client-$rate"
  stop_server
  run=$work/server-$rate/run
  python3 bench/fill_lost_poses.py "$run/trajectory.txt" 0 "$frames" > "$work/every-$rate.txt"
  python3 - "$rate" "$work/client-$rate/summary.json" "$run/summary.json" \
    "$(ate "$run/trajectory.txt")" "$(ate "$work/every-$rate.txt")" <<'PY'
import json, sys
rate, client, server = sys.argv[1], json.load(open(sys.argv[2])), json.load(open(sys.argv[3]))
mapped, every = json.loads(sys.argv[4]), json.loads(sys.argv[5])
cell = lambda a: f"{a['ate_rmse_cm']:.2f} ({a['ate_rmse_aligned_cm']:.2f})"
print(f"{rate:5s} {client['frames_sent']:5d} {client['frames_mapped']:7d} {client['frames_dropped']:8d} "
      f"{server['dropped_frames']:16d} {server['lost_frames']:5d} {cell(mapped):>26s} {cell(every):>26s}")
PY
done
