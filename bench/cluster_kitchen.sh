#!/usr/bin/env bash
# The cluster on the 7-Scenes kitchen, on this machine: a JetStream
# nats-server on loopback, the frames split between two sensors.
#
# 1. Throughput: the frames published first (sensor a, then b, as fast as
#    the bus takes them), then fused by 1 and by 2 workers, each with
#    rayon's threads on both cores, and each pinned to a core of its own
#    (taskset, one rayon thread); frames/s from the
#    first frame published to the map fetched with every frame fused
#    (`cluster fetch --wait`). Each fetched map is compared with
#    `reconstruct` of the same frames (the sensors in folder order).
# 2. Failover: three workers, both sensors publishing at 30 frames/s at
#    once, one worker killed with SIGKILL halfway; the lag `cluster status`
#    shows every half second, then the fetched map against `cluster replay`
#    of the stream (same file, F-score at 1 mm) and the frames fused once.
# 3. The bytes on the bus per sensor per second, at 30 frames/s.
#
# Usage: bench/cluster_kitchen.sh [FRAMES] [CODEC]   (defaults 300, default)
# Needs ../shared beside the repository (or DEPTHMESH_SHARED) and nats-server.
set -euo pipefail
cd "$(dirname "$0")/.."
frames=${1:-300}
codec=${2:-default}
half=$((frames / 2))
need_kitchen=1
source bench/setup.sh
nats_server=$(command -v nats-server || echo /usr/sbin/nats-server)
[[ -x $nats_server ]] || { echo "error: nats-server not found (apt-get install nats-server)" >&2; exit 1; }
dm=./target/release/depthmesh
mkdir -p "$work/ports"
"$nats_server" -js -a 127.0.0.1 -p -1 --http_port 0 -sd "$work/js" --ports_file_dir "$work/ports" > "$work/nats.log" 2>&1 &
nats_pid=$!
trap 'kill $(jobs -p) 2>/dev/null; rm -rf "$work"' EXIT
for _ in $(seq 100); do ls "$work"/ports/*.ports > /dev/null 2>&1 && break; sleep 0.1; done
url=$(python3 -c "import json,glob,sys; print(json.load(open(glob.glob(sys.argv[1] + '/*.ports')[0]))['nats'][0])" "$work/ports")

now() { date +%s.%N; }
publish() { # site sensor range rate -> JSON summary
  "$dm" stream "$data" --frames "$3" --nats "$url" --site "$1" --sensor "$2" --rate "$4" --codec "$codec" --quiet
}
workers() { # site count cores -> starts them (cores 0: rayon's threads on every core; 1: each on a core of its own)
  for i in $(seq "$2"); do
    pin=()
    [[ $3 == 1 ]] && pin=(taskset -c $((i - 1)))
    RAYON_NUM_THREADS=$3 "${pin[@]}" "$dm" cluster worker --nats "$url" --site "$1" --name "w$i" --lease-seconds 2 \
      > "$work/$1-w$i.log" 2>&1 &
  done
}
balanced() { # site count: waits until every shard is owned and shared out
  for _ in $(seq 200); do
    "$dm" cluster status --nats "$url" --site "$1" 2> /dev/null | python3 -c "
import json, sys
try:
    s = json.load(sys.stdin)
except ValueError:
    sys.exit(1)  # no worker has set the site up yet
n, shards = int(sys.argv[1]), len(s['shards'])
owned = [len(w['shards']) for w in s['workers']]
sys.exit(0 if len(owned) == n and sum(owned) == shards and min(owned) >= shards // n - 1 else 1)" "$2" && return 0
    sleep 0.1
  done
  echo "error: workers did not share the shards" >&2; exit 1
}
same_triangles() { # a.ply b.ply -> "yes"/"no" (triangles as exact corner positions, any order)
  python3 - "$1" "$2" <<'PY'
import struct, sys
def triangles(path):
    b = open(path, 'rb').read()
    end = b.index(b'end_header\n') + 11
    head = b[:end].decode().split('\n'); body = b[end:]
    nv = int(next(l for l in head if l.startswith('element vertex')).split()[2])
    nf = int(next(l for l in head if l.startswith('element face')).split()[2])
    size = sum({'float': 4, 'uchar': 1}[l.split()[1]] for l in head if l.startswith('property') and 'list' not in l)
    v = [body[i * size:i * size + 12] for i in range(nv)]
    at, out = nv * size, []
    for _ in range(nf):
        t = [v[j] for j in struct.unpack('<3i', body[at + 1:at + 13])]; at += 13
        k = t.index(min(t)); out.append(tuple(t[k:] + t[:k]))
    return sorted(out)
print('yes' if triangles(sys.argv[1]) == triangles(sys.argv[2]) else 'no')
PY
}

"$dm" reconstruct "$data" --frames "0..$frames" --out "$work/reconstruct" --quiet
echo "| workers | cores each | frames/s | = reconstruct (triangles) | frames fused once |"
echo "|---|---|---|---|---|"
declare -A fps
for setup in "1 0" "2 0" "1 1" "2 1"; do
  read -r count threads <<< "$setup"
  site="t${count}x${threads}"
  workers "$site" "$count" "$threads"
  balanced "$site" "$count"
  start=$(now)
  publish "$site" a "0..$half" max > "$work/$site-a.json"
  publish "$site" b "$half..$frames" max > "$work/$site-b.json"
  "$dm" cluster fetch --nats "$url" --site "$site" --wait -o "$work/$site.ply" > "$work/$site.json"
  end=$(now)
  kill $(jobs -p | grep -v "^$nats_pid$") 2> /dev/null || true
  wait $(jobs -p | grep -v "^$nats_pid$") 2> /dev/null || true
  fps[$setup]=$(python3 -c "print(f'{$frames / ($end - $start):.1f}')")
  once=$(python3 -c "import json; r = json.load(open('$work/$site.json')); print(r['every_frame_fused_once'], r['frames_fused_min'], '/', r['frames_in_stream'])")
  echo "| $count | ${threads/#0/both (shared)} | ${fps[$setup]} | $(same_triangles "$work/$site.ply" "$work/reconstruct/mesh.ply") | $once |"
done
python3 -c "print(f'two workers over one: {${fps[2 0]} / ${fps[1 0]}:.2f}x sharing both cores, {${fps[2 1]} / ${fps[1 1]}:.2f}x on a core each')"

site=failover
workers "$site" 3 0
balanced "$site" 3
publish "$site" a "0..$half" 30 > "$work/a.json" &
pa=$!
publish "$site" b "$half..$frames" 30 > "$work/b.json" &
pb=$!
start=$(now)
cat > "$work/lag.py" <<'PY'
import json, sys
s = json.load(sys.stdin)
sensors = ", ".join(f"{k} {v['lag']}" for k, v in s["sensors"].items())
workers = " ".join(f"{w['id']}:{len(w['shards'])}" for w in s["workers"])
print(f"  {sys.argv[1]} s: stream {s['stream_last']}, lag {s['lag']} ({sensors}), "
      f"shards {workers}, {s['frames_per_second']:.0f} frames/s")
sys.exit(0 if s["lag"] == 0 and s["stream_last"] == int(sys.argv[2]) else 1)
PY
kill_at=$(python3 -c "print($half / 30 / 2)")
echo "lag while two sensors publish at 30 frames/s; w2 killed at $kill_at s:"
killed=0
# Until the sensors are done, w2 is killed and the lag is back to zero; at most two minutes.
while (($(python3 -c "print(int($(now) - $start))") < 120)); do
  t=$(python3 -c "print(f'{$(now) - $start:.1f}')")
  if ((killed == 0)) && python3 -c "import sys; sys.exit(0 if $t >= $kill_at else 1)"; then
    pkill -9 -f -- "--site $site --name w2 " || true
    killed=1
    echo "  $t s: w2 killed"
  fi
  if "$dm" cluster status --nats "$url" --site "$site" | python3 "$work/lag.py" "$t" "$frames" &&
    ((killed == 1)) && ! kill -0 "$pa" 2> /dev/null && ! kill -0 "$pb" 2> /dev/null; then
    break
  fi
  sleep 0.5
done
"$dm" cluster fetch --nats "$url" --site "$site" --wait -o "$work/fetched.ply" > "$work/fetch.json"
"$dm" cluster replay --nats "$url" --site "$site" -o "$work/replayed.ply" --quiet > "$work/replay.json"
cmp -s "$work/fetched.ply" "$work/replayed.ply" && same=identical || same=different
fscore=$("$PY" "$shared/tools/mesh_compare.py" "$work/fetched.ply" "$work/replayed.ply" --threshold 0.001 | python3 -c "import json,sys; print(json.loads(sys.stdin.read().strip().splitlines()[-1])['fscore'])")
python3 - "$work/fetch.json" "$work/replay.json" "$same" "$fscore" "$work/a.json" "$work/b.json" <<'PY'
import json, sys
f, r = (json.load(open(p)) for p in sys.argv[1:3])
print(f"fetched: {f['triangles']} triangles, {f['frames_fused_min']}-{f['frames_fused_max']} of {f['frames_in_stream']} frames fused by every shard, fused once: {f['every_frame_fused_once']}")
print(f"replay:  {r['triangles']} triangles, {r['frames']} frames, {r['fps']:.1f} frames/s in one process")
print(f"fetched vs replay: {sys.argv[3]} files, F-score at 1 mm {float(sys.argv[4]):.4f}")
for p in sys.argv[5:7]:
    s = json.load(open(p))
    print(f"sensor: {s['frames']} frames, {s['bytes'] / s['frames'] / 1e3:.1f} kB a frame, {s['bytes'] / s['frames'] * 30 / 1e6:.2f} MB/s at 30 frames/s")
print(f"checkpoints: {f['checkpoint_bytes'] / 1e6:.1f} MB of segments for {f['blocks']} blocks")
PY
