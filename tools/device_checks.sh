#!/usr/bin/env bash
# What the open issues ask a lent GPU to measure, in one call of the device tool (its time is
# short: this runs in a few minutes on an H100 or H200):
#   crowd.md       issue 14, goal 4: a 10 000-car frame against one car's, split into the
#                  GPU's passes and the host's parts, the cars posed on the GPU and on the
#                  host (tools/crowd_gpu.sh)
#   gi_gather.md   issue 19: the GPU's GI gathers timed against each other on the box
#                  (tools/gi_gather_gpu.sh)
#   data/          issue 14: the harness's paper, resolution and instance records on the GPU
#                  (and the scene caster's rays, the cast scenario),
#                  merged into the copy of docs/data/bench.json (and .csv) that the device has;
#                  copy both over docs/data here, then `voxray bench --report-only` redraws
#                  docs/benchmarks.md's tables and charts from them
#
# Usage, after `cargo build --release && ../shared/tools/device-pack`, through the device
# tool's run with carry [".device"]:
#   OUT_DIR=$OUT bash tools/device_checks.sh bash .device/run.sh
# Environment: OUT_DIR (required), FRAMES (gathers' frames, default 20), BENCH_ARGS (extra
# arguments for the harness, for a quick trial: "--frames 2 --warmup 1 --sweep-cars 1,10").
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
out=${OUT_DIR:?set OUT_DIR to the folder that comes back}
if [ $# -gt 0 ]; then vox=("$@"); else vox=("$root/target/release/voxray"); fi
mkdir -p "$out/data"
step() { echo "== $1 ($(date -u +%T))" >&2; }

step "crowd"
OUT_DIR= bash "$root/tools/crowd_gpu.sh" "${vox[@]}" > "$out/crowd.md"
cat "$out/crowd.md"
step "GI gathers"
FRAMES=${FRAMES:-20} bash "$root/tools/gi_gather_gpu.sh" "${vox[@]}" > "$out/gi_gather.md"
cat "$out/gi_gather.md"
step "harness: paper, resolution, instances, cast"
# shellcheck disable=SC2086 # BENCH_ARGS is a list of arguments
"${vox[@]}" bench --scenarios paper,resolution,instances,cast --backends gpu --out-dir "$root/docs/data" \
  --charts-dir "$(mktemp -d)" --no-docs --memory-budget 48G ${BENCH_ARGS:-} >&2
cp "$root/docs/data/bench.json" "$root/docs/data/bench.csv" "$out/data/"
step "done"
