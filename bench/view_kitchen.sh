#!/usr/bin/env bash
# The browser view on a real session: 7-Scenes kitchen frames streamed to
# `depthmesh serve` (TSDF at 1 cm) as fast as it maps.
#   1. Mapping speed (the stream's end-to-end frames/s) with no viewer and
#      with three viewers (`depthmesh watch`, which receive what the page
#      receives without drawing), alternating, ROUNDS rounds each.
#   2. Bytes sent to one viewer over the session, against the final mesh as
#      a meshopt-compressed GLB (gltfpack -c and -cc, pinned from npm).
#   3. The page in headless Chromium (software GL) on the finished session:
#      time to show every triangle and its drawing rate while orbiting;
#      a screenshot is written to docs/view-kitchen.png (or $SCREENSHOT).
#
# Usage: bench/view_kitchen.sh [FRAMES] [ROUNDS] [VOXEL] [RATE]
#   (defaults 300, 2, 0.01 m, max: as fast as the server maps; 30 is the sensor's pace)
# Needs ../shared beside the repository (or DEPTHMESH_SHARED), npm, and
# chromium with chromedriver (.ci/browser installs them). Loopback only.
set -euo pipefail
cd "$(dirname "$0")/.."
frames=${1:-300}
rounds=${2:-2}
voxel=${3:-0.01}
rate=${4:-max}
source bench/serve_common.sh
start_server --out "$work/server" --max-sessions 4 --voxel "$voxel" --idle-timeout 600
limit=$((frames + 300))
listed() {
  curl -sf "$url/api/sessions?token=bench" | grep -q "\"name\":\"$1\""
}
run() { # run NAME VIEWERS
  local name=$1 viewers=$2 pids=()
  timeout "$limit" "$bin" stream "$data" --server "$url" --token bench --frames "0..$frames" \
    --rate "$rate" --session "$name" --quiet --out "$work/client-$name" &
  local stream=$!
  if ((viewers > 0)); then
    for _ in $(seq 200); do listed "$name" && break; sleep 0.05; done
    for i in $(seq "$viewers"); do
      timeout "$limit" "$bin" watch "$name" --server "$url" --token bench >"$work/watch-$name-$i.json" &
      pids+=($!)
    done
  fi
  wait "$stream"
  for p in "${pids[@]}"; do wait "$p"; done
}
for r in $(seq "$rounds"); do
  run "none-$r" 0
  run "three-$r" 3
done
mesh=$work/server/three-1/mesh.ply
"$bin" export "$mesh" -o "$work/final.glb" --quiet
npm install --prefix "$work/npm" --no-audit --no-fund --silent gltfpack@1.3.0 >/dev/null
gltfpack=$work/npm/node_modules/.bin/gltfpack
"$gltfpack" -i "$work/final.glb" -o "$work/final-c.glb" -c >/dev/null
"$gltfpack" -i "$work/final.glb" -o "$work/final-cc.glb" -cc >/dev/null
triangles=$(python3 -c "import json; print(json.load(open('$work/server/three-1/summary.json'))['triangles'])")
shot=${SCREENSHOT:-docs/view-kitchen.png}
mkdir -p "$(dirname "$shot")"
page=$(python3 bench/view_browser.py "$url/view/three-1#token=bench" "$triangles" "$shot" 10)
python3 - "$work" "$rounds" "$frames" "$page" <<'PY'
import glob, json, os, statistics, sys
work, rounds, frames, page = sys.argv[1], int(sys.argv[2]), sys.argv[3], json.loads(sys.argv[4])
load = lambda p: json.load(open(p))
fps = {k: [load(f"{work}/client-{k}-{r}/summary.json")["fps"] for r in range(1, rounds + 1)]
       for k in ("none", "three")}
for k, v in fps.items():
    print(f"{k:5} viewers: stream fps per round {', '.join(f'{x:.1f}' for x in v)} (median {statistics.median(v):.1f})")
ratio = statistics.median(fps["three"]) / statistics.median(fps["none"])
print(f"three viewers / none: {ratio:.3f} ({(1 - ratio) * 100:+.1f} % slower)")
w = [load(p) for p in sorted(glob.glob(f"{work}/watch-three-1-*.json"))]
s = load(f"{work}/server/three-1/summary.json")
size = lambda n: os.path.getsize(f"{work}/{n}")
print(f"kitchen {frames} frames, voxel {s['voxel']:.3f} m: {s['triangles']} triangles, {s['vertices']} vertices")
for i, x in enumerate(w, 1):
    assert x["ended"] and x["triangles"] == s["triangles"], x
    print(f"viewer {i}: {x['bytes']} bytes in {x['part_messages']} part messages, ends holding {x['triangles']} triangles in {x['parts']} parts")
glb, c, cc = size("final.glb"), size("final-c.glb"), size("final-cc.glb")
print(f"final mesh: GLB {glb} bytes; meshopt-compressed GLB (gltfpack -c) {c} bytes, (-cc) {cc} bytes")
b = w[0]["bytes"]
print(f"bytes to one viewer / compressed GLB: {b / c:.2f}x (-c), {b / cc:.2f}x (-cc)")
print(f"page (headless Chromium, software GL, 1280x800) on the finished session: {json.dumps(page)}")
PY
