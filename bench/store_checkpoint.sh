#!/usr/bin/env bash
# What the map store costs: `reconstruct` of the 7-Scenes kitchen (given
# poses; MAP tsdf at 1 cm, planes or mabdi, each with its defaults) with and
# without `--store` at the default checkpoint interval (30 frames),
# alternating, ROUNDS rounds each; wall-clock frames/s of the whole run, the
# checkpoints' own time, and the store's size (for tsdf, bytes per voxel
# beside the 4 bytes a voxel takes in memory).
#
# Usage: bench/store_checkpoint.sh [FRAMES] [ROUNDS] [MAP]   (defaults 300, 3, tsdf)
# Needs ../shared beside the repository (or DEPTHMESH_SHARED).
set -euo pipefail
cd "$(dirname "$0")/.."
frames=${1:-300}
rounds=${2:-3}
map=${3:-tsdf}
need_kitchen=1
source bench/setup.sh
bin=./target/release/depthmesh
for r in $(seq "$rounds"); do
  for mode in none store; do
    extra=()
    [[ $mode == store ]] && extra=(--store "$work/$mode-$r.store")
    start=$(date +%s.%N)
    "$bin" reconstruct "$data" --frames "0..$frames" --map "$map" --quiet --out "$work/$mode-$r" "${extra[@]}" >/dev/null
    end=$(date +%s.%N)
    echo "$mode $r $start $end" >>"$work/times"
  done
done
"$bin" info "$work/store-1.store" >"$work/info.json"
python3 - "$work" "$frames" <<'PY'
import json, statistics, sys
work, frames = sys.argv[1], int(sys.argv[2])
runs = {}
for line in open(f"{work}/times"):
    mode, r, a, b = line.split()
    runs.setdefault(mode, []).append(frames / (float(b) - float(a)))
for mode, fps in runs.items():
    print(f"{mode:5}: whole-run frames/s per round {', '.join(f'{x:.1f}' for x in fps)} (median {statistics.median(fps):.1f})")
ratio = statistics.median(runs["store"]) / statistics.median(runs["none"])
print(f"with --store / without: {ratio:.3f} ({(1 - ratio) * 100:+.1f} % slower)")
s = json.load(open(f"{work}/store-1/summary.json"))["store"]
info = json.load(open(f"{work}/info.json"))
print(f"checkpoints: {s['checkpoints']}, frame loop held up {s['stall_ms_mean']:.1f} ms each, {s['stall_ms_total']:.0f} ms in all; "
      f"{s['blocks_written']} blocks or cells, {s['bytes_copied']} bytes copied for the commits, {s['bytes_written']} compressed bytes written")
if info["map"] == "tsdf":
    print(f"store: {info['blocks']} blocks, {info['voxels']} voxels; compressed blocks "
          f"{s['bytes_written'] / max(1, s['blocks_written']) / 512:.2f} B/voxel as written, file "
          f"{info['file_bytes']} B = {info['file_bytes_per_voxel']:.2f} B/voxel (in memory: 4 B/voxel)")
else:
    held = f"{info['cells']} cells" if info["map"] == "planes" else f"{info['triangles']} triangles"
    print(f"store: {info['map']}, {held}, file {info['file_bytes']} B")
PY
