#!/usr/bin/env bash
# Reproduces the shipped checkpoint sonar_realism/assets/cdfcvae_default.* and the `oculus` calibration from the
# real Oculus set's fit recording (the held-out one, Oculus_20250805_171720, is never seen): scripts/train_sensor.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA="${SONAR_REALISM_DATA:-../shared/data}"
FIT=Oculus_20250805_173650
CALIBRATE_ARGS="--match $FIT" RECORDINGS=$FIT \
  exec scripts/train_sensor.sh oculus default "$DATA/real/oculus_polar_seabed/dataset" "$@"
