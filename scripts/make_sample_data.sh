#!/usr/bin/env bash
# Regenerate the committed sample scene sample_data/tabletop5 (5 YCB objects, 640x480).
# Deterministic: the same r2s version gives identical files. The convex-decomposition memo
# that synth leaves in the scene (.cache/) is dropped; `r2s export` recomputes it if needed.
set -euo pipefail
cd "$(dirname "$0")/.."
R2S="${R2S:-.venv/bin/r2s}"
OUT=sample_data/tabletop5
"$R2S" synth "$OUT" --objects ycb --count 5 --seed 47 --width 640 --height 480
rm -rf "$OUT/.cache"
du -sh "$OUT"
