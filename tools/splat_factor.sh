#!/bin/bash
# The square-size factor of the splat renderer against the ray tracer (docs/splats.md):
# renders the car on its ground (1280×768) and 100 cars (640×384) traced and splatted at
# several factors, then compares coverage (instance AOVs) and the displayed images.
# Usage: tools/splat_factor.sh [VOXRAY] [OUT_DIR]   (needs python3 with numpy and pillow)
set -euo pipefail
B=${1:-target/release/voxray}
D=${2:-/tmp/splat-factor}
mkdir -p "$D"
for view in "near:" "far:--cars 100 --width 640 --height 384"; do
  name=${view%%:*}; args=${view#*:}
  # shellcheck disable=SC2086
  "$B" render $args --no-hit-buffer --out "$D/t_$name.png" --aov-dir "$D/t_$name" > /dev/null 2>&1
  for f in 0.75 1.0 1.25 1.5 1.75 2.0; do
    # shellcheck disable=SC2086
    "$B" render $args --no-hit-buffer --renderer splat --splat-factor $f --out "$D/s_${name}_$f.png" --aov-dir "$D/s_${name}_$f" > /dev/null 2>&1
  done
done
python3 - "$D" <<'PY'
import sys
import numpy as np
from PIL import Image
d = sys.argv[1]
print("| view | factor | coverage mismatch | holes | bloat | image RMSE |\n|---|---|---|---|---|---|")
for name in ["near", "far"]:
    ti = np.load(f"{d}/t_{name}/instance.npy")
    tp = np.asarray(Image.open(f"{d}/t_{name}.png")).astype(float) / 255
    for f in ["0.75", "1.0", "1.25", "1.5", "1.75", "2.0"]:
        si = np.load(f"{d}/s_{name}_{f}/instance.npy")
        sp = np.asarray(Image.open(f"{d}/s_{name}_{f}.png")).astype(float) / 255
        holes, bloat = ((ti >= 0) & (si < 0)).mean(), ((ti < 0) & (si >= 0)).mean()
        rmse = np.sqrt(((tp - sp) ** 2).mean())
        print(f"| {name} | {f} | {100 * (ti != si).mean():.3f}% | {100 * holes:.3f}% | {100 * bloat:.3f}% | {rmse:.4f} |")
PY
