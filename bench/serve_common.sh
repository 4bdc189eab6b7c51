# Sourced by the benchmarks of `depthmesh serve`: finds the 7-Scenes kitchen
# frames (`data`; ../shared beside the repository, or DEPTHMESH_SHARED),
# builds depthmesh in release (`bin`), makes a scratch folder (`work`) and
# defines `start_server ARGS...` (a server on a free loopback port with token
# `bench`; sets `server` and `url`, stopping the one before) and
# `stop_server`. Everything is stopped and removed on exit. Run from the
# repository root.
shared=$(realpath -m "${DEPTHMESH_SHARED:-../shared}")
data=$shared/data/7scenes-redkitchen
if [[ ! -d $data ]]; then
  echo "error: 7-Scenes frames not found in $data (set DEPTHMESH_SHARED)" >&2
  exit 1
fi
cargo build --release --quiet
bin=./target/release/depthmesh
work=$(mktemp -d)
server=
stop_server() {
  if [[ -n $server ]]; then
    kill "$server" 2>/dev/null || true
    wait "$server" 2>/dev/null || true
  fi
  server=
}
trap 'stop_server; rm -rf "$work"' EXIT
start_server() {
  stop_server
  "$bin" serve --bind 127.0.0.1:0 --token bench "$@" >"$work/serve.out" 2>/dev/null &
  server=$!
  for _ in $(seq 50); do [[ -s $work/serve.out ]] && break; sleep 0.1; done
  url=$(head -1 "$work/serve.out" | sed 's/^listening on //')
}
