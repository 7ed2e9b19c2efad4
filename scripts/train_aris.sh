#!/usr/bin/env bash
# The second sensor: the ARIS Explorer 3000 water-tank set, fit on its 30-degree setting, the 24.3-degree one held
# out (scripts/aris_split.py), through the same workflow (scripts/train_sensor.sh) ->
# sonar_realism/assets/cdfcvae_aris.* and the `aris` calibration. Cycle 1 uses 240 of the 1109 fit frames.
set -euo pipefail
cd "$(dirname "$0")/.."
[ -d runs/aris/fit ] || python scripts/aris_split.py --out runs/aris
CALIBRATE_ARGS="--limit 200 --vertical-fov 14" exec scripts/train_sensor.sh aris aris runs/aris/fit --max-frames 240 "$@"
