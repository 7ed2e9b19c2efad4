#!/usr/bin/env bash
# Reproduces the realism evaluation of docs/RESULTS.md (Table I and the further metrics, on the held-out Oculus
# recording): splits the real Oculus set by recording, trains the small CPU CycleGAN baseline on the same
# training data as the shipped cDFCVAE (the fit recording, 400 frames of the calibrated simulator) as its authors
# train it, on crops of the frames at their own resolution (24 epochs, about 45 minutes on 2 cores), then evaluates
# raw sim, the shipped cDFCVAE, the paper configuration and the CycleGAN on 120 fresh calibrated-sim frames. Pass a
# seed (first argument) to repeat with other realism-CNN inits.
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

[ -f runs/sim_calibrated_train/manifest.json ] || sonar-realism simulate --calibration oculus --n 400 --seed 0 \
  --out runs/sim_calibrated_train --quiet
[ -f runs/sim_calibrated_eval/manifest.json ] || sonar-realism simulate --calibration oculus --n 120 --seed 101 \
  --out runs/sim_calibrated_eval --quiet
if [ ! -f runs/cyclegan_crop/cyclegan.safetensors ]; then
  OMP_NUM_THREADS=2 sonar-realism train --model cyclegan --real runs/real_173650 --sim runs/sim_calibrated_train \
    --out runs/cyclegan_crop --config scripts/cyclegan_small.json --crop 128 --epochs 24 --batch-size 1 --seed 0
fi
MODELS=(--model cdfcvae=sonar_realism/assets/cdfcvae_default.safetensors
        --model paper=sonar_realism/assets/cdfcvae_paper.safetensors
        --model cyclegan=runs/cyclegan_crop/cyclegan.safetensors)
# --yardstick: the training recording, real frames from outside the one the realism CNN learns "real" from
sonar-realism evaluate --real runs/real_171720 --yardstick runs/real_173650 --sim runs/sim_calibrated_eval --n 4 \
  --seed "$SEED" "${MODELS[@]}" --out "runs/eval_oculus_seed$SEED"
