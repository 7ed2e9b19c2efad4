#!/usr/bin/env bash
# Reproduces the shipped checkpoint sonar_realism/assets/cdfcvae_default.* on a 2-core CPU in under 2 hours:
#   1. calibrate the simulator to the real Oculus set's fit recording (never the held-out one),
#   2. render 400 randomised frames of that sensor,
#   3. train the default configuration (scripts/cdfcvae_default.json): cycle 1 on the fit recording's real
#      frames, the speckle fit, cycle 2 on the calibrated simulator's frames.
# Resumable: run it again after an interruption and training continues from runs/cdfcvae_default/state.*.
# Pass --epochs1/--epochs2 to go further on a GPU (the paper trains far longer).
set -euo pipefail
cd "$(dirname "$0")/.."
DATA="${SONAR_REALISM_DATA:-../shared/data}"
REAL="$DATA/real/oculus_polar_seabed/dataset"
FIT=Oculus_20250805_173650
RUN=runs/cdfcvae_default
mkdir -p "$RUN"
[ -f "$RUN/calibration.json" ] || sonar-realism calibrate --real "$REAL" --match "$FIT" --out "$RUN/calibration.json"
[ -f "$RUN/sim/manifest.json" ] || sonar-realism simulate --calibration "$RUN/calibration.json" --n 400 --seed 0 \
  --workers 2 --out "$RUN/sim" --quiet
RESUME=()
[ -f "$RUN/state.json" ] && RESUME=(--resume)
sonar-realism train --real "$REAL" --recordings "$FIT" --sim "$RUN/sim" --out "$RUN" \
  --config scripts/cdfcvae_default.json \
  --epochs1 30 --epochs2 15 "${RESUME[@]}" "$@"
cp "$RUN/model.safetensors" sonar_realism/assets/cdfcvae_default.safetensors
cp "$RUN/model.json" sonar_realism/assets/cdfcvae_default.json
cp "$RUN/calibration.json" sonar_realism/assets/oculus_calibration.json
