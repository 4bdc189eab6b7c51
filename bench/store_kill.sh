#!/usr/bin/env bash
# A run killed and resumed ends as one never interrupted, on real frames:
# `reconstruct --store` of the 7-Scenes kitchen (frames 0..FRAMES, TSDF 1 cm,
# with --track unless TRACK=0) is killed with SIGKILL KILLS times, each time
# SECONDS after it was (re)started, resumed to the end, and its mesh.ply and
# trajectory.txt compared byte for byte with an uninterrupted run's.
#
# Usage: bench/store_kill.sh [FRAMES] [KILLS] [SECONDS]   (defaults 300, 3, 2.5)
# Needs ../shared beside the repository (or DEPTHMESH_SHARED).
set -euo pipefail
cd "$(dirname "$0")/.."
frames=${1:-300}
kills=${2:-3}
seconds=${3:-2.5}
need_kitchen=1
source bench/setup.sh
bin=./target/release/depthmesh
track=()
[[ ${TRACK:-1} == 1 ]] && track=(--track)
"$bin" reconstruct "$data" --frames "0..$frames" "${track[@]}" --quiet --out "$work/reference" >/dev/null
for k in $(seq "$kills"); do
  args=(--store "$work/map.store" --force)
  [[ -f $work/map.store ]] && args+=(--resume)
  "$bin" reconstruct "$data" --frames "0..$frames" "${track[@]}" --quiet --out "$work/run" "${args[@]}" >/dev/null 2>&1 &
  pid=$!
  sleep "$seconds"
  if kill -9 "$pid" 2>/dev/null; then
    wait "$pid" 2>/dev/null || true
    echo "kill $k: $("$bin" info "$work/map.store" | python3 -c 'import json, sys; print(json.load(sys.stdin)["records"])') frames committed"
  else
    wait "$pid"
    echo "kill $k: the run had already finished"
  fi
done
"$bin" reconstruct "$data" --frames "0..$frames" "${track[@]}" --quiet --out "$work/run" \
  --store "$work/map.store" --force --resume >/dev/null
for f in mesh.ply trajectory.txt; do
  if cmp -s "$work/reference/$f" "$work/run/$f"; then
    echo "$f: identical to the uninterrupted run"
  else
    echo "$f: DIFFERS from the uninterrupted run"
  fi
done
