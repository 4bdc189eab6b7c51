#!/usr/bin/env bash
# Bounded memory on long walks: the simulated sensor walks down a corridor
# (floor, a wall, boxes and posts; generated here), once straight for LENGTH
# metres and once there and back (LENGTH/2 out, then it turns round and walks
# back past what it saw). Each walk's TSDF map is built three times: without
# bounds, with --active-radius (freed blocks meshed into chunks), and with
# --active-radius and --store (freed blocks kept in the store and brought back
# when the camera returns). Reports the peak resident memory of each run
# (/usr/bin/time -v), the blocks held, freed and brought back, the chunks
# written, and whether each bounded run's mesh.ply (chunks joined with the
# rest) holds exactly the unbounded run's triangles, whole vertex records
# compared (position, normal and colour bytes). Without a store the
# there-and-back walk cannot match: the region it returns to starts empty.
#
# Usage: bench/tsdf_bounded.sh [LENGTH] [VOXEL] [RADIUS]     (defaults 60, 0.02, reach + 0.1)
set -euo pipefail
cd "$(dirname "$0")/.."
length=${1:-60}
voxel=${2:-0.02}
radius=${3:-}
if [[ ! -x /usr/bin/time ]]; then
  echo "error: /usr/bin/time (GNU time) is needed for peak memory" >&2
  exit 1
fi
cargo build --release --quiet
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
# Scene and the two walks looking ahead to the wall (TUM camera-to-world poses).
python3 bench/corridor_walk.py "$length" "$work"
frames=$(wc -l < "$work/straight.txt")
run() {
  local walk=$1 name=$2; shift 2
  /usr/bin/time -v ./target/release/depthmesh simulate --scene "$work/corridor.toml" --map tsdf \
    --voxel "$voxel" --path "tum:$work/$walk.txt" --iterations "$frames" --quiet --out "$work/$walk-$name" "$@" \
    2> "$work/$walk-$name.time" || { cat "$work/$walk-$name.time" >&2; exit 1; }
  grep "Maximum resident" "$work/$walk-$name.time" | awk '{print $NF}' > "$work/$walk-$name.rss"
}
if [[ -z $radius ]]; then
  # The simulated Kinect's reach: 4 m along its corner rays (640×480, 60° vertical), plus the truncation.
  radius=$(python3 -c "import math; t = math.tan(math.radians(30)); print(round(4 * math.sqrt(1 + t * t + (t * 4 / 3) ** 2) + 4 * $voxel + 0.1, 3))")
fi
for walk in straight there-and-back; do
  run "$walk" unbounded
  run "$walk" bounded --active-radius "$radius"
  run "$walk" store --active-radius "$radius" --store "$work/$walk.store"
done
python3 - "$work" "$length" "$voxel" <<'PY'
import json, os, struct, sys
work, length, voxel = sys.argv[1], sys.argv[2], sys.argv[3]
SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
         "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}
FORMATS = {1: "B", 2: "H", 4: "I"}
def triangles(path):
    """Triangles as sorted tuples of their corners' whole vertex records (every property's
    bytes: position, normal, colour), each rotated to start at its smallest corner."""
    data = open(path, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    head = data[:end].decode().split("\n")
    assert "format binary_little_endian 1.0" in head, f"{path}: not binary little-endian PLY"
    nv = nf = size = 0; element = None; count_type = index_type = None
    for line in head:
        words = line.split()
        if words[:1] == ["element"]:
            element = words[1]
            if element == "vertex": nv = int(words[2])
            if element == "face": nf = int(words[2])
        elif words[:1] == ["property"] and element == "vertex":
            size += SIZES[words[1]]
        elif words[:2] == ["property", "list"] and element == "face":
            count_type, index_type = words[2], words[3]
    verts = [data[end + i * size:end + (i + 1) * size] for i in range(nv)]
    cs, isz = SIZES[count_type], SIZES[index_type]
    out, at = [], end + nv * size
    for _ in range(nf):
        n = struct.unpack_from("<" + FORMATS[cs], data, at)[0]
        assert n == 3, f"{path}: a face with {n} corners"
        a, b, c = struct.unpack_from("<3" + FORMATS[isz], data, at + cs); at += cs + 3 * isz
        t = (verts[a], verts[b], verts[c]); k = t.index(min(t))
        out.append(t[k:] + t[:k])
    out.sort()
    return out
for walk in ["straight", "there-and-back"]:
    runs = {}
    for name in ["unbounded", "bounded", "store"]:
        summary = json.load(open(f"{work}/{walk}-{name}/summary.json"))
        rss = int(open(f"{work}/{walk}-{name}.rss").read()) / 1024
        runs[name] = (summary, rss)
    full, rss = runs["unbounded"]
    truth = triangles(f"{work}/{walk}-unbounded/mesh.ply")
    print(f"{walk} walk, {length} m, {full['frames']} frames, voxel {voxel} m")
    print(f"  unbounded     peak RSS {rss:7.1f} MB   blocks {full['map_bytes'] // (512 * 4):6d}   "
          f"triangles {full['triangles']}   {full['fps']:.1f} frames/s")
    for name, label in [("bounded", "bounded"), ("store", "bounded+store")]:
        s, rss = runs[name]
        same = triangles(f"{work}/{walk}-{name}/mesh.ply") == truth
        extra = ""
        if name == "store":
            size = os.path.getsize(f"{work}/{walk}.store")
            extra = f"   brought back {s.get('loaded_blocks', 0)}   store {size / 1e6:.1f} MB"
        print(f"  {label:13s} peak RSS {rss:7.1f} MB   peak blocks {s['peak_blocks']:6d}   freed {s['evicted_blocks']}{extra}   "
              f"chunks {s['chunks']}   triangles {s['triangles']}   {s['fps']:.1f} frames/s   (radius {s['active_radius']:.2f} m)")
        print(f"    mesh.ply == unbounded mesh (exact triangles, whole vertex records): {same}")
PY
