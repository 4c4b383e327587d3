#!/usr/bin/env bash
# The worked example of docs/diagnosis.md, end to end (about 10 minutes on 2 cores):
#   control drapes and drapes with a hidden effect (synth), a reference preset fitted on the control drapes,
#   the diagnosis of the hidden-effect drapes with it, the recommended effect fitted with the material from the
#   diagnosis's refit (fit --init), the diagnosis of that fit (its history chart holds every version), and the
#   control drapes' diagnosis.
# Usage: tools/diagnosis_example.sh [OUT_DIR] [EFFECT=VALUE]   (defaults: out/diagnosis_example density_variation=0.3)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
OUT="${1:-$ROOT/out/diagnosis_example}"
HIDDEN="${2:-density_variation=0.3}"
DENSITY=0.192   # Cotton Blue's area density (kg/m^2, the dataset manifest): the material synth drapes by default
LEVEL=1         # circle1: the coarse Cusick mesh, so that the whole example runs in minutes
run() { echo "+ drapelab $*" >&2; "$ROOT/drapelab" "$@"; }
mkdir -p "$OUT"
run synth --density $DENSITY --count 6 --seed 301 --mesh-level $LEVEL --out "$OUT/control" --force
run synth --effects "$HIDDEN" --density $DENSITY --count 6 --seed 301 --mesh-level $LEVEL --out "$OUT/hidden" --force
run fit --images "$OUT"/control/fabric_00/silhouettes/*.png --density $DENSITY --model bdp --epochs 15 --no-calibration \
    --mesh-level $LEVEL --seed 0 --name reference --out "$OUT/reference.json"
run diagnose --preset "$OUT/reference.json" --images "$OUT"/hidden/fabric_00/silhouettes/*.png --time-budget 300 --report "$OUT/report"
rec="$(/usr/bin/python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["recommended"] or "")' "$OUT/report/diagnosis.json")"
if [ -n "$rec" ]; then
  run fit --init "$OUT/report/presets/$rec.json" --effects "$rec" --images "$OUT"/hidden/fabric_00/silhouettes/*.png \
      --epochs 15 --no-calibration --seed 0 --name "reference + $rec" --out "$OUT/with_effect.json"
  run diagnose --preset "$OUT/with_effect.json" --images "$OUT"/hidden/fabric_00/silhouettes/*.png --time-budget 120 \
      --report "$OUT/report_after"
fi
run diagnose --preset "$OUT/reference.json" --images "$OUT"/control/fabric_00/silhouettes/*.png --time-budget 120 --report "$OUT/report_control"
