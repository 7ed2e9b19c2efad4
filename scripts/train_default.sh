#!/usr/bin/env bash
# Reproduces the shipped checkpoint sonar_realism/assets/cdfcvae_default.*: the simulator's clean frames of
# constructed and organic scenes (cycle 2) and the real Oculus set beside the checkout (cycle 1, split by
# recording). Epoch limits are small enough for a 2-core CPU; pass --epochs1/--epochs2 to go further on a GPU.
set -euo pipefail
cd "$(dirname "$0")/.."
REAL="${REAL:-${SONAR_REALISM_DATA:-../shared/data}/real/oculus_polar_seabed/dataset}"
for scene in constructed organic; do
  sonar-realism simulate --scene "$scene" --n 200 --seed 11 --out "runs/sim_train/$scene" --quiet
done
sonar-realism train --real "$REAL" --sim runs/sim_train --out runs/cdfcvae_default \
  --config scripts/cdfcvae_default.json --epochs1 14 --epochs2 6 "$@"
cp runs/cdfcvae_default/model.safetensors sonar_realism/assets/cdfcvae_default.safetensors
cp runs/cdfcvae_default/model.json sonar_realism/assets/cdfcvae_default.json
