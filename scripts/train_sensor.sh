#!/usr/bin/env bash
# The calibrate -> simulate -> train workflow for one sensor, on a 2-core CPU in under 2 hours:
#   1. calibrate the simulator to the sensor's fit recording(s) (never the held-out ones),
#   2. render 400 randomised frames of that sensor,
#   3. train the default configuration (scripts/cdfcvae_default.json): cycle 1 on the real frames, cycle 2 on the
#      calibrated simulator's frames, then the learned texture drawn on those frames against the real ones,
# then ship the checkpoint as sonar_realism/assets/cdfcvae_CHECKPOINT.* and the calibration as
# sonar_realism/assets/SENSOR_calibration.json (so `simulate --calibration SENSOR` finds it).
#
#   scripts/train_sensor.sh SENSOR CHECKPOINT REAL_DIR [train options...]
#   env CALIBRATE_ARGS: more `calibrate` options (e.g. "--match RECORDING --limit 200")
#   env RECORDINGS:     `train --recordings` (the fit recordings' names; default: every recording in REAL_DIR)
#   env CONFIG:         the training config (default scripts/cdfcvae_default.json)
#
# Resumable: run it again after an interruption and training continues from runs/cdfcvae_CHECKPOINT/state.*.
# Pass --epochs1/--epochs2 to go further on a GPU (the paper trains far longer).
set -euo pipefail
cd "$(dirname "$0")/.."
SENSOR=$1 CHECKPOINT=$2 REAL=$3
shift 3
RUN=runs/cdfcvae_$CHECKPOINT
mkdir -p "$RUN"
# shellcheck disable=SC2086  # CALIBRATE_ARGS is a list of options
[ -f "$RUN/calibration.json" ] || sonar-realism calibrate --real "$REAL" ${CALIBRATE_ARGS:-} --out "$RUN/calibration.json"
[ -f "$RUN/sim/manifest.json" ] || sonar-realism simulate --calibration "$RUN/calibration.json" --n 400 --seed 0 \
  --workers 2 --out "$RUN/sim" --quiet
OPTIONS=()
[ -f "$RUN/state.json" ] && OPTIONS+=(--resume)
[ -n "${RECORDINGS:-}" ] && OPTIONS+=(--recordings "$RECORDINGS")
sonar-realism train --real "$REAL" --sim "$RUN/sim" --out "$RUN" --config "${CONFIG:-scripts/cdfcvae_default.json}" \
  --epochs1 30 --epochs2 15 "${OPTIONS[@]}" "$@"
cp "$RUN/model.safetensors" "sonar_realism/assets/cdfcvae_$CHECKPOINT.safetensors"
cp "$RUN/model.json" "sonar_realism/assets/cdfcvae_$CHECKPOINT.json"
cp "$RUN/calibration.json" "sonar_realism/assets/${SENSOR}_calibration.json"
