#!/usr/bin/env bash
# One lent-GPU session (the machine sees this repository only, not ../shared; see scripts/pack_grid_frames.py):
#   1. the model benchmark's GPU rows and goals (bench/bench_model.py --device cuda), on an otherwise idle GPU;
#   2. then side by side: the shipped cDFCVAE configuration with the paper's epoch budget (80 + 60, early stopping
#      as always) and the stock CycleGAN (ngf 64, 9 residual blocks, 200 epochs, lr falling over the last 100),
#      each capped at TRAIN_SECONDS, on the packed fit recording and 400 calibrated-sim frames. The CycleGAN trains
#      on the model grid here: the frames at their own resolution, which its `--crop` recipe (scripts/evaluate.sh)
#      needs, do not fit in the 64 MiB the machine receives beside the repository.
# What comes back, under $OUT: logs.tgz (logs, benchmark table, checkpoint JSONs, loss curves), the cDFCVAE
# checkpoint's weights (its learned texture is left unfitted: fit it where the real frames are, at their own
# resolution, with scripts/refit_texture.py --texture learned), and the CycleGAN's sim -> real generator in parts
# of at most 15 MB (`cat cyclegan_gab.part-* > cyclegan.safetensors`, beside the returned cyclegan.json).
#
# Here, first:
#   sonar-realism simulate --calibration oculus --n 400 --seed 0 --out runs/sim_calibrated_train --quiet
#   python scripts/pack_grid_frames.py --src ../shared/data/real/oculus_polar_seabed/dataset \
#       --recordings Oculus_20250805_173650 --out runs/gpu/real_fit.npz
#   python scripts/pack_grid_frames.py --src runs/sim_calibrated_train --out runs/gpu/sim_train.npz
# then run this there with runs/gpu and the wheels of rosbags and its needs (.whl) carried.
# env: TRAIN_SECONDS (330), CG_EPOCHS (200), EPOCHS1 (80), EPOCHS2 (60), BENCH_DEVICE (cuda): smaller for a dry run.
set -uo pipefail
cd "$(dirname "$0")/.."
RUN=runs/gpu
OUT="${OUT:-$RUN/out}"
LOGS=$RUN/logs
mkdir -p "$OUT" "$LOGS"
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
TRAIN_SECONDS="${TRAIN_SECONDS:-330}"

{ nvidia-smi; python3 -c 'import torch; print(torch.__version__, torch.cuda.is_available())'; nproc; date -u; } \
  > "$LOGS/env.txt" 2>&1
timeout 150 python3 bench/bench_model.py --device "${BENCH_DEVICE:-cuda}" > "$LOGS/bench_model.md" \
  2> "$LOGS/bench_model.log"
echo "bench rc $?" >> "$LOGS/env.txt"

python3 - "$RUN/cdfcvae_gpu.json" <<'EOF'
import json, sys
config = json.load(open("scripts/cdfcvae_default.json"))
config["texture_fit"] = {"steps": 1}  # a placeholder: the real texture is fitted at full resolution afterwards
json.dump(config, open(sys.argv[1], "w"))
EOF
timeout "$TRAIN_SECONDS" python3 -m sonar_realism.cli train --model cyclegan --real $RUN/real_fit.npz \
  --sim $RUN/sim_train.npz --out $RUN/cyclegan --epochs "${CG_EPOCHS:-200}" --batch-size 8 --save-every 20 --seed 0 \
  > "$LOGS/cyclegan.log" 2>&1 &
timeout "$TRAIN_SECONDS" python3 -m sonar_realism.cli train --real $RUN/real_fit.npz --sim $RUN/sim_train.npz \
  --recordings Oculus_20250805_173650 --config $RUN/cdfcvae_gpu.json --out $RUN/cdfcvae \
  --epochs1 "${EPOCHS1:-80}" --epochs2 "${EPOCHS2:-60}" --seed 0 > "$LOGS/cdfcvae.log" 2>&1 &
wait
date -u >> "$LOGS/env.txt"

python3 - "$RUN/cyclegan/cyclegan.safetensors" "$OUT/cyclegan_gab.safetensors" <<'EOF'
import sys
from safetensors.torch import load_file, save_file
weights = load_file(sys.argv[1])
save_file({k: v for k, v in weights.items() if k.startswith("g_ab.")}, sys.argv[2])
EOF
[ -f "$OUT/cyclegan_gab.safetensors" ] && split -b 15000000 "$OUT/cyclegan_gab.safetensors" "$OUT/cyclegan_gab.part-" \
  && rm "$OUT/cyclegan_gab.safetensors"
cp $RUN/cdfcvae/model.safetensors "$OUT/cdfcvae_model.safetensors" 2>/dev/null \
  || split -b 15000000 $RUN/cdfcvae/state.safetensors "$OUT/cdfcvae_state.part-"
tar czf "$OUT/logs.tgz" -C $RUN logs cdfcvae_gpu.json $(cd $RUN && ls cyclegan/cyclegan.json cdfcvae/*.json cdfcvae/*.png \
  2>/dev/null)
cat "$LOGS/bench_model.md"
for log in cyclegan cdfcvae; do echo "== $log"; tr '\r' '\n' < "$LOGS/$log.log" | tail -4; done
ls -la "$OUT"
