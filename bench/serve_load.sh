#!/usr/bin/env bash
# Load on one `depthmesh serve`: N sensor clients at once, each streaming
# 7-Scenes kitchen frames as a live 30 frames/s sensor (--realtime: the server
# maps the newest frame and drops what it cannot keep up with), for each
# back-end and N = 1..MAX_CLIENTS. Prints per run: frames mapped and dropped,
# the clients' mapped frames/s, latency p50/p99 (frame sent to verdict
# received, worst client) and the server's peak resident memory.
# A back-end "keeps up" with N clients when under 1 % of their frames are dropped.
#
# Usage: bench/serve_load.sh [FRAMES] [MAX_CLIENTS] [MAPS]   (defaults 150, 4, "tsdf mabdi planes")
# Needs ../shared beside the repository (or DEPTHMESH_SHARED). Loopback only;
# every client and server is bounded in time and stopped at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
frames=${1:-150}
max=${2:-4}
maps=${3:-tsdf mabdi planes}
source bench/serve_common.sh
# A run may take at most this long (frames at 30/s, plus the final mesh).
limit=$((frames / 30 + 120))
printf '%-7s %7s %14s %14s %10s %12s %12s %10s\n' map clients mapped dropped "fps/client" "p50 ms" "p99 ms" "peak MB"
for map in $maps; do
  start_server --map "$map" --out "$work/server-$map" --max-sessions "$max"
  for n in $(seq "$max"); do
    clients=()
    for i in $(seq "$n"); do
      timeout "$limit" "$bin" stream "$data" --server "$url" --token bench --frames "0..$frames" \
        --realtime --rate 30 --session "$map-$n-$i" --quiet --out "$work/client-$map-$n-$i" &
      clients+=($!)
    done
    peak=0
    while kill -0 "${clients[@]}" 2>/dev/null; do
      rss=$(awk '/VmRSS/ {print $2}' "/proc/$server/status")
      ((rss > peak)) && peak=$rss
      sleep 0.2
    done
    for c in "${clients[@]}"; do wait "$c"; done
    python3 - "$map" "$n" "$peak" "$work"/client-"$map-$n"-*/summary.json <<'PY'
import json, sys
map_, n, peak = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
s = [json.load(open(f)) for f in sys.argv[4:]]
mapped = sum(x["frames_mapped"] for x in s); dropped = sum(x["frames_dropped"] for x in s)
sent = sum(x["frames_sent"] for x in s)
fps = sum(x["fps"] for x in s) / len(s)
p50 = max(x["latency_ms_p50"] for x in s); p99 = max(x["latency_ms_p99"] for x in s)
keeps = "keeps up" if dropped <= 0.01 * sent else ""
print(f"{map_:<7} {n:>7} {mapped:>8}/{sent:<5} {dropped:>8} ({100*dropped/sent:3.0f}%) {fps:>10.1f} {p50:>12.1f} {p99:>12.1f} {peak/1024:>10.0f}  {keeps}")
PY
  done
  stop_server
done
