# Sourced by the scripts that compare depthmesh with the reference tools on
# the 7-Scenes kitchen frames: finds ../shared (or DEPTHMESH_SHARED) and the
# frames, sets up the reference Python (PY), builds depthmesh in release and
# makes a scratch folder (work) removed on exit. Run from the repository root.
shared=${DEPTHMESH_SHARED:-../shared}
data=$shared/data/7scenes-redkitchen
if [[ ! -x $shared/tools/setup-anchors.sh || ! -d $data ]]; then
  echo "error: reference tools or 7-Scenes frames not found under $shared (set DEPTHMESH_SHARED)" >&2
  exit 1
fi
PY=$("$shared/tools/setup-anchors.sh")
cargo build --release --quiet
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
