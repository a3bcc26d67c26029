#!/usr/bin/env bash
# The GPU's GI gathers timed against each other on the box (docs/gi.md, issue 19's target),
# from the passes' timestamp queries. Per image size: the shade pass without GI over every
# pixel (--no-hit-buffer: with the hit buffer a still box keeps its colours and that pass
# shades almost nothing), then each gather's passes. A gather's own time is its shade pass
# less that one, plus its cache passes. Prints a Markdown table.
#
# Usage: tools/gi_gather_gpu.sh [COMMAND...]   (default: target/release/voxray)
#   on a lent GPU machine, after ../shared/tools/device-pack:
#   FRAMES=20 bash tools/gi_gather_gpu.sh bash .device/run.sh
# Environment: FRAMES (frames per run, the median is kept; default 20), SIZES (default
# "320x240 640x480 1280x960").
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
if [ $# -gt 0 ]; then vox=("$@"); else vox=("$root/target/release/voxray"); fi
frames=${FRAMES:-20}
sizes=${SIZES:-"320x240 640x480 1280x960"}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$out}

# The shade pass and the three cache passes of one run (ms, medians; 0 where absent).
passes() {
  local w=$1 h=$2
  shift 2
  "${vox[@]}" render --scene "$root/models/box/box.obj" --camera-json "$root/models/box/camera.json" \
    --lights-json "$root/models/box/lights.json" --width "$w" --height "$h" --backend gpu \
    --frames "$frames" --out "$out/f.png" "$@" 2>&1 |
    awk '/GPU passes \(timestamp/ { for (i = 1; i <= NF; i++) if ($i == "shade") s = $(i + 1) }
         /radiance-cache passes/ { for (i = 1; i <= NF; i++) {
             if ($i == "placement") p = $(i + 1); if ($i == "tracing") t = $(i + 1); if ($i == "convolution") c = $(i + 1) } }
         END { if (s == "") { print "no GPU pass times in the output" > "/dev/stderr"; exit 1 }
               printf "%s %s %s %s\n", s, p + 0, t + 0, c + 0 }'
}

echo "$("${vox[@]}" render --width 8 --height 8 --backend gpu --out "$out/probe.png" 2>&1 | grep -m1 '^backend:' || true)"
echo
echo "| image | shade, no GI, every pixel | per-pixel cones: gather | half: gather | caches 16²: placement + tracing + convolution + blend = gather | caches 8²: likewise | cones ÷ caches 8² |"
echo "|---|---|---|---|---|---|---|"
for size in $sizes; do
  w=${size%x*}; h=${size#*x}
  read -r base _ _ _ < <(passes "$w" "$h" --no-hit-buffer)
  read -r pix _ _ _ < <(passes "$w" "$h" --gi --gi-gather pixels)
  read -r half _ _ _ < <(passes "$w" "$h" --gi --gi-gather half)
  read -r c16 p16 t16 v16 < <(passes "$w" "$h" --gi --gi-gather caches)
  read -r c8 p8 t8 v8 < <(passes "$w" "$h" --gi --gi-gather caches --gi-cache-res 8)
  awk -v size="$size" -v base="$base" -v pix="$pix" -v half="$half" \
    -v c16="$c16" -v p16="$p16" -v t16="$t16" -v v16="$v16" -v c8="$c8" -v p8="$p8" -v t8="$t8" -v v8="$v8" 'BEGIN {
      g = pix - base; b16 = c16 - base; b8 = c8 - base
      s16 = p16 + t16 + v16 + b16; s8 = p8 + t8 + v8 + b8
      printf "| %s | %.2f | %.2f | %.2f | %.2f + %.2f + %.2f + %.2f = %.2f | %.2f + %.2f + %.2f + %.2f = %.2f | %.2f× |\n",
        size, base, g, half - base, p16, t16, v16, b16, s16, p8, t8, v8, b8, s8, (s8 > 0 ? g / s8 : 0) }'
done
