#!/usr/bin/env bash
# A full MABDI iteration (render D, render E, classify, mesh, append, removal
# evidence) against Open3D's RaycastingScene (Embree) rendering E alone, for
# the same global mesh M and the same poses, side by side on this machine.
#
# Needs the reference tools beside the repository (../shared/tools, or set
# DEPTHMESH_SHARED to the folder holding tools/).
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/setup.sh
ours=$(./target/release/depthmesh bench mabdi --out "$work" "$@" | tail -1)
read -r fx cx cy < <(python3 -c 'import json,sys; d=json.loads(sys.argv[1]); print(d["fx"], d["cx"], d["cy"])' "$ours")
theirs=$("$PY" "$shared/tools/open3d_raycast.py" "$work/mesh.ply" "$work/poses.txt" --fx "$fx" --cx "$cx" --cy "$cy" | tail -1)
python3 - "$ours" "$theirs" <<'PY'
import json, sys
ours, theirs = json.loads(sys.argv[1]), json.loads(sys.argv[2])
print(f"global mesh M: {ours['triangles']} triangles, {ours['iterations']} poses, {ours['width']}x{ours['height']}, {ours['threads']} threads")
print(f"depthmesh full MABDI iteration  {ours['median_ms']:7.1f} ms  ({ours['hz']:.1f} Hz)")
for k in ("render_d_ms", "render_e_ms", "classify_ms", "removal_ms", "mesh_append_ms"):
    print(f"  {k:<28}  {ours[k]:7.1f} ms")
print(f"Open3D RaycastingScene, E only  {theirs['median_ms']:7.1f} ms")
print(f"ratio (Open3D E / depthmesh iteration): {theirs['median_ms'] / ours['median_ms']:.2f}x")
PY
