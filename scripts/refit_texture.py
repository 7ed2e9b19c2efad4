"""Refit a cDFCVAE checkpoint's texture layer with this version's rule, keeping its weights.

What training does after cycle 1 (`fit_model_texture`; a learned texture drawn on simulated frames: after cycle 2;
the decoder is not trained in cycle 2, so this equals a retrain's texture), for a checkpoint trained before the
rule changed. The texture layer starts where `train` starts it (a fresh model's, built after
`torch.manual_seed(--seed)`), never from the checkpoint's fitted one: with the training run's seed (its config's
`seed`, 0 by default) and frames, the refit is that run's texture step, weight for weight, written in the
checkpoint's own precision. Optionally it switches
the mean field's fine detail (`--detail input`, models/cdfcvae.py), which the speckle is fitted around. Fit on the
training recordings only, never on held-out ones. `--texture learned` swaps the speckle statistics for the learned
texture (models/learned_texture.py; its adversarial fit takes about 0.15 s a step on 2 CPU cores), drawn while it
is fitted on the decoded means of `--sim` frames (what the translator will texture; the shipped default's recipe).
`--sim` may be given more than once: the folders' frames pooled in order, e.g. to draw the texture on other
simulators' frames as well (a probe; `train` draws on its one `--sim`; docs/RESULTS.md, 2026-11-29):

    python scripts/refit_texture.py --checkpoint runs/v10/model.safetensors \\
        --real ../shared/data/real/oculus_polar_seabed/dataset --recordings Oculus_20250805_173650 \\
        --detail input --out runs/v10d1/model.safetensors
    python scripts/refit_texture.py --checkpoint sonar_realism/assets/cdfcvae_default.safetensors \\
        --real ../shared/data/real/oculus_polar_seabed/dataset --recordings Oculus_20250805_173650 \\
        --texture learned --sim runs/cdfcvae_default/sim --out runs/learned/model.safetensors
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import torch
from safetensors import safe_open

from sonar_realism.config import from_dict
from sonar_realism.models.cdfcvae import CDFCVAE, load_checkpoint, retextured_info, round_to_half, save_checkpoint
from sonar_realism.models.learned_texture import TextureFitConfig
from sonar_realism.models.train import fit_model_texture, texture_frames


def stored_in_half(checkpoint: str | Path) -> bool:
    """Whether the checkpoint holds its floating weights in half precision (`train`'s default)."""
    with safe_open(str(checkpoint), "pt") as weights:
        return any(str(weights.get_slice(key).get_dtype()) == "F16" for key in weights.keys())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True, help="cDFCVAE checkpoint (.safetensors with its .json)")
    parser.add_argument("--real", required=True, help="the real recording(s) it was trained on")
    parser.add_argument("--recordings", help="comma-separated training recordings (default: every one in --real)")
    parser.add_argument("--detail", choices=["none", "input"], help="the mean field's fine detail (default: as is)")
    parser.add_argument("--texture", choices=["speckle", "learned"], help="the texture layer (default: as is)")
    parser.add_argument("--sim", action="append", help="simulated frames the learned texture is drawn on while it "
                        "is fitted (repeatable: the folders' frames pooled; default: the real frames' own decoded "
                        "means)")
    parser.add_argument("--texture-fit", help="JSON of TextureFitConfig fields for the learned texture's fit "
                                              "(default: TextureFitConfig's)")
    parser.add_argument("--seed", type=int, default=0,
                        help="the training run's seed (its config's `seed`): the texture's start and fit")
    parser.add_argument("--out", required=True, help="where to write the refitted checkpoint")
    args = parser.parse_args()

    model, info = load_checkpoint(args.checkpoint)
    changes = {key: value for key, value in (("detail", args.detail), ("texture", args.texture)) if value is not None}
    # A learned texture's fit trains the generators it is given; from the checkpoint's fitted ones it would be a
    # second pass (the shipped texture of 2026-11-28 was one: docs/RESULTS.md), not what `train` makes.
    torch.manual_seed(args.seed)
    refitted = CDFCVAE(dataclasses.replace(model.cfg, **changes))
    kept = {key: value for key, value in model.state_dict().items() if not key.startswith("texture.")}
    missing = refitted.load_state_dict(kept, strict=False).missing_keys  # the texture layer is fitted below
    assert all(key.startswith("texture.") for key in missing), missing
    model = refitted.eval()
    half = stored_in_half(args.checkpoint)
    if half:  # as `train` fits a half-precision run's texture: on every weight as its checkpoint holds them
        round_to_half(model)
    schedule = (from_dict(TextureFitConfig, json.loads(Path(args.texture_fit).read_text()), args.texture_fit)
                if args.texture_fit else TextureFitConfig())
    recordings = {name.strip() for name in args.recordings.split(",") if name.strip()} if args.recordings else None
    fit_model_texture(model, texture_frames(args.real, recordings), info.get("normalisation", "frame_max"),
                      torch.device("cpu"), args.seed, schedule, progress=True,
                      sim_frames=[frame for folder in args.sim for frame in texture_frames(folder)] if args.sim
                      else None)
    extra = {**retextured_info(info), "texture_refit_from": Path(args.checkpoint).name}
    print(f"wrote {save_checkpoint(model, args.out, extra, half=half)}")


if __name__ == "__main__":
    main()
