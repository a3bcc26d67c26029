#!/usr/bin/env bash
# Issue 14's goal 4 on a GPU backend: a 10 000-car crowd's frame against one car's, with the
# frame split into the GPU's passes and the host's parts (docs/benchmarks.md, steps 86-89).
# Runs the harness's instance scenario (BVH rows, --no-docs) once with the cars posed on the
# GPU (--crowd-posing gpu, step 89) and once on the host (--crowd-posing host), and prints a
# Markdown table for each from its records: frame median, ratio to one car, GPU passes
# (trace and shade timestamps), the crowd's pose and refit passes (gpu_crowd_ms), the host's
# part (gpu_host_ms), and of it posing with the transform update (pose_ms), the render up
# to its submit (gpu_submit_ms) and the rest (the wait past the passes, the read-back).
#
# Usage: tools/crowd_gpu.sh [COMMAND...]   (default: target/release/voxray)
#   on a lent GPU machine, after ../shared/tools/device-pack:
#   OUT_DIR=$OUT/crowd bash tools/crowd_gpu.sh bash .device/run.sh
# Environment: CARS (default "1,10000"), FRAMES (timed frames per round, default 20),
# POSINGS (default "gpu host"), OUT_DIR (where the records are kept, one folder per posing;
# default a temporary folder, removed after).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
if [ $# -gt 0 ]; then vox=("$@"); else vox=("$root/target/release/voxray"); fi
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
out=${OUT_DIR:-$tmp/records}
mkdir -p "$out"
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$tmp}

for posing in ${POSINGS:-gpu host}; do
mkdir -p "$out/$posing"
"${vox[@]}" bench --scenarios instances --backends gpu --sweep-cars "${CARS:-1,10000}" \
  --frames "${FRAMES:-20}" --warmup 5 --sweep-frames 1 --no-docs --crowd-posing "$posing" \
  --out-dir "$out/$posing" >&2
echo "Cars posed on the $posing:"
echo

awk '
  # One CSV line into f[1..n], quoted fields (with commas and doubled quotes) kept whole.
  function split_csv(line, f,    n, i, c, q, cur) {
    n = 0; q = 0; cur = ""
    for (i = 1; i <= length(line); i++) {
      c = substr(line, i, 1)
      if (q) {
        if (c == "\"" && substr(line, i + 1, 1) == "\"") { cur = cur c; i++ }
        else if (c == "\"") q = 0
        else cur = cur c
      } else if (c == "\"") q = 1
      else if (c == ",") { f[++n] = cur; cur = "" }
      else cur = cur c
    }
    f[++n] = cur
    return n
  }
  NR == 1 { n = split_csv($0, h); for (i = 1; i <= n; i++) col[h[i]] = i; next }
  {
    split_csv($0, f)
    if (f[col["setting"]] != "BVH" || f[col["backend_kind"]] != "gpu") next
    k = ++rows
    cars[k] = f[col["x"]]; ms[k] = f[col["median_ms"]]; backend = f[col["backend"]]
    passes[k] = f[col["gpu_trace_ms"]] + f[col["gpu_shade_ms"]]
    host[k] = f[col["gpu_host_ms"]]; pose[k] = f[col["pose_ms"]]; submit[k] = f[col["gpu_submit_ms"]]
    crowd[k] = f[col["gpu_crowd_ms"]]
    if (cars[k] == 1) one = ms[k]
  }
  END {
    if (rows == 0) { print "no GPU BVH records: was a GPU backend found?" > "/dev/stderr"; exit 1 }
    print backend
    print ""
    print "| cars | frame ms | ÷ one car | GPU passes ms | crowd passes ms | host ms | posing and update | render to its submit | the rest |"
    print "|---|---|---|---|---|---|---|---|---|"
    for (k = 1; k <= rows; k++)
      printf "| %s | %.3f | %s | %.3f | %s | %.3f | %.3f | %.3f | %.3f |\n", cars[k], ms[k],
        (one > 0 ? sprintf("%.1f×", ms[k] / one) : "–"), passes[k], (crowd[k] == "" ? "–" : sprintf("%.3f", crowd[k])),
        host[k], pose[k], submit[k], host[k] - pose[k] - submit[k]
  }' "$out/$posing/bench.csv"
echo
done
