# Sourced by the scripts that compare depthmesh with the reference tools:
# finds ../shared (or DEPTHMESH_SHARED, as an absolute path in `shared`) and
# the 7-Scenes kitchen frames (`data`; a script that needs them sets
# need_kitchen=1 first), sets up the reference Python (PY), builds depthmesh
# in release and makes a scratch folder (work) removed on exit; defines
# frames_folder and link_frame, for folders of links to kitchen frames.
# Run from the repository root.
shared=$(realpath -m "${DEPTHMESH_SHARED:-../shared}")
data=$shared/data/7scenes-redkitchen
if [[ ! -x $shared/tools/setup-anchors.sh ]]; then
  echo "error: reference tools not found in $shared/tools (set DEPTHMESH_SHARED)" >&2
  exit 1
fi
if [[ ${need_kitchen:-0} == 1 && ! -d $data ]]; then
  echo "error: 7-Scenes frames not found in $data (set DEPTHMESH_SHARED)" >&2
  exit 1
fi
PY=$("$shared/tools/setup-anchors.sh")
cargo build --release --quiet
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# Makes folder $1 for links to kitchen frames, with the camera's intrinsics.
frames_folder() {
  mkdir "$1"
  cp "$data/camera-intrinsics.txt" "$1/" 2>/dev/null || true
}

# Links every file of kitchen frame $1 into folder $3 as frame $2.
link_frame() {
  local f
  for f in "$data"/frame-$(printf %06d "$1").*; do
    ln -s "$f" "$3/frame-$(printf %06d "$2").${f#*/frame-??????.}"
  done
}
