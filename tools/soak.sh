#!/usr/bin/env bash
# Soak: runs the demo (CPU renderer, one thread, 640×384) under a virtual X display for
# SECONDS (default 600) and prints its resident memory every 30 s; a leak shows as growth.
# Usage: cargo build --release && tools/soak.sh [SECONDS]   (needs xvfb-run)
set -u
secs=${1:-600}
voxray=${VOXRAY:-$(dirname "$0")/../target/release/voxray}
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
log=$(mktemp)
timeout $((secs + 60)) xvfb-run -a "$voxray" --threads 1 demo --backend cpu --width 640 --height 384 \
  --frames 100000000 --exit >"$log" 2>&1 &
wrapper=$!
# The demo itself: the voxray process descending from this script's xvfb-run (not the
# wrapper, nor another voxray running on the machine).
descends() {
  local p=$1
  while [ "$p" -gt 1 ]; do
    [ "$p" = "$wrapper" ] && return 0
    p=$(awk '{print $4}' /proc/"$p"/stat 2>/dev/null) || return 1
    [ -n "$p" ] || return 1
  done
  return 1
}
pid=
for _ in $(seq 60); do
  for p in $(pgrep -x voxray); do
    descends "$p" && pid=$p
  done
  [ -n "$pid" ] && break
  sleep 1
done
[ -n "${pid:-}" ] || { echo "the demo did not start:" >&2; cat "$log" >&2; exit 1; }
start=$(date +%s)
while kill -0 "$pid" 2>/dev/null; do
  now=$(($(date +%s) - start))
  echo "$now s: $(awk '/VmRSS/ {print $2, $3}' /proc/"$pid"/status 2>/dev/null)"
  if [ "$now" -ge "$secs" ]; then
    kill "$pid"
    break
  fi
  sleep 30
done
