#!/usr/bin/env bash
# Reproduces the realism evaluation of docs/RESULTS.md (Table I and the further metrics, both translators, both
# real domains): splits the real Oculus set by recording, trains the small CPU CycleGAN baseline on the same
# training data as the shipped cDFCVAE, then evaluates raw sim, cDFCVAE and CycleGAN. Run scripts/train_default.sh
# first (it makes runs/sim_train and runs/cdfcvae_default). Pass --seed N to repeat with other scenes and CNN init.
set -euo pipefail
cd "$(dirname "$0")/.."
SHARED="${SONAR_REALISM_DATA:-../shared/data}/real"
SEED="${1:-0}"
# One thread per process: on 2 shared cores OpenMP's spinning threads made steps up to 10x slower.
export OMP_NUM_THREADS=1

link_recording() {  # link_recording NAME_PREFIX DEST: every PNG of one Oculus recording
  mkdir -p "$2"
  find "$SHARED/oculus_polar_seabed/dataset" -name "$1*.png" -exec ln -sf "$(pwd)/{}" "$2/" \;
}
link_recording Oculus_20250805_173650 runs/real_173650   # the cDFCVAE's training recording
link_recording Oculus_20250805_171720 runs/real_171720   # held out: no translator trained on it
mkdir -p runs/real_aris_every9
for f in "$SHARED"/marine_debris_watertank/watertank-segmentation/Images/marine-debris-aris3k-*.png; do
  n="${f##*-}"; n="${n%.png}"
  if (( n % 9 == 0 )); then ln -sf "$(realpath "$f")" runs/real_aris_every9/; fi
done

if [ ! -f runs/cyclegan_small/cyclegan.safetensors ]; then
  sonar-realism train --model cyclegan --real runs/real_173650 --sim runs/sim_train --out runs/cyclegan_small \
    --config scripts/cyclegan_small.json --epochs 2 --batch-size 1 --seed 0
fi
MODELS=(--model cdfcvae=runs/cdfcvae_default/model.safetensors --model cyclegan=runs/cyclegan_small/cyclegan.safetensors)
sonar-realism evaluate --real runs/real_171720 --n-sim 60 --n 4 --seed "$SEED" "${MODELS[@]}" \
  --out "runs/eval_oculus_seed$SEED"
sonar-realism evaluate --real runs/real_aris_every9 --max-real 208 --n-sim 60 --n 4 --seed "$SEED" "${MODELS[@]}" \
  --out "runs/eval_aris_seed$SEED"
