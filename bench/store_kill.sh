#!/usr/bin/env bash
# A run killed and resumed ends as one never interrupted, on real frames:
# `reconstruct --store` of the 7-Scenes kitchen (frames 0..FRAMES, TSDF 1 cm,
# with --track unless TRACK=0) is killed with SIGKILL KILLS times, each time
# SECONDS after it was (re)started, resumed to the end, and its mesh.ply and
# trajectory.txt compared byte for byte with an uninterrupted run's.
# SECONDS given as MIN..MAX kills each time after a random delay in that
# range (bash's RANDOM, seeded with SEED, default 1): points a fixed delay
# never reaches, such as a resumed run's start-up, where it replaces the
# killed run's folder.
#
# Usage: bench/store_kill.sh [FRAMES] [KILLS] [SECONDS | MIN..MAX]   (defaults 300, 3, 2.5)
# Needs ../shared beside the repository (or DEPTHMESH_SHARED).
set -euo pipefail
cd "$(dirname "$0")/.."
frames=${1:-300}
kills=${2:-3}
seconds=${3:-2.5}
RANDOM=${SEED:-1}
number='([0-9]*\.)?[0-9]+'
if [[ $seconds =~ ^($number)\.\.($number)$ ]]; then
  range=("${BASH_REMATCH[1]}" "${BASH_REMATCH[3]}")
elif ! [[ $seconds =~ ^$number$ ]]; then
  echo "error: SECONDS must be a number or MIN..MAX, got \"$seconds\"" >&2
  exit 1
fi
need_kitchen=1
source bench/setup.sh
bin=./target/release/depthmesh
track=()
[[ ${TRACK:-1} == 1 ]] && track=(--track)
"$bin" reconstruct "$data" --frames "0..$frames" "${track[@]}" --quiet --out "$work/reference" >/dev/null
for k in $(seq "$kills"); do
  # Drawn before the run starts, so the delay counts from its start, and
  # outside the substitution: a subshell reseeds $RANDOM, so a draw there
  # would not follow SEED.
  if [[ -v range ]]; then
    draw=$RANDOM
    delay=$(python3 -c "import sys; a, b = map(float, sys.argv[1:3]); print(round(a + (b - a) * int(sys.argv[3]) / 32767, 3))" "${range[@]}" "$draw")
  else
    delay=$seconds
  fi
  args=(--store "$work/map.store" --force)
  [[ -f $work/map.store ]] && args+=(--resume)
  "$bin" reconstruct "$data" --frames "0..$frames" "${track[@]}" --quiet --out "$work/run" "${args[@]}" >/dev/null 2>&1 &
  pid=$!
  sleep "$delay"
  if kill -9 "$pid" 2>/dev/null; then
    wait "$pid" 2>/dev/null || true
    if [[ -f $work/map.store ]]; then
      echo "kill $k after $delay s: $("$bin" info "$work/map.store" | python3 -c 'import json, sys; print(json.load(sys.stdin)["records"])') frames committed"
    else
      echo "kill $k after $delay s: before the store was made"
    fi
  else
    wait "$pid"
    echo "kill $k after $delay s: the run had already finished"
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
