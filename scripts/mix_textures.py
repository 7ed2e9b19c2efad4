"""Join the learned textures of checkpoints that share every other weight into one checkpoint whose texture draws
from all their generators in turn (models/learned_texture.py: a mixture).

`train` fits a mixture's generators itself (`model.texture_generators`, one per core); this joins generators fitted
apart, in other runs of `scripts/refit_texture.py --texture learned --seed K` or on other machines:

    python scripts/mix_textures.py --checkpoint runs/texfit/seed0/model.safetensors \\
        --checkpoint runs/texfit/seed1/model.safetensors --out runs/texfit/mix01/model.safetensors
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import torch

from sonar_realism.errors import ConfigError
from sonar_realism.models.cdfcvae import CDFCVAE, load_checkpoint, retextured_info, save_checkpoint
from sonar_realism.models.learned_texture import LearnedTexture, mixture_of


def mixed(paths: list[str]) -> tuple[CDFCVAE, dict]:
    """The first checkpoint with the texture of all of them; ConfigError naming the first that differs in any
    other weight or in its architecture."""
    models = [load_checkpoint(path) for path in paths]
    first, info = models[0]
    architecture = dataclasses.replace(first.cfg, texture_generators=1)
    weights = {key: value for key, value in first.state_dict().items() if not key.startswith("texture.")}
    for path, (model, _) in zip(paths, models, strict=True):
        if not isinstance(model.texture, LearnedTexture):
            raise ConfigError(f"{path}: model.texture is {model.cfg.texture!r}; only learned textures mix")
        if dataclasses.replace(model.cfg, texture_generators=1) != architecture:
            raise ConfigError(f"{path}: model config differs from {paths[0]}'s beyond texture_generators")
        differing = [key for key, value in weights.items() if not torch.equal(value, model.state_dict()[key])]
        if differing:
            raise ConfigError(f"{path}: {differing[0]} differs from {paths[0]}'s ({len(differing)} tensors in all); "
                              "only textures fitted on the same translator mix")
    texture = mixture_of([model.texture for model, _ in models])  # type: ignore[misc]
    joined = CDFCVAE(dataclasses.replace(first.cfg, texture_generators=len(texture.generators)))
    joined.load_state_dict({**weights, **{f"texture.{key}": value for key, value in texture.state_dict().items()}})
    return joined.eval(), info


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", action="append", required=True,
                        help="a cDFCVAE checkpoint with a learned texture; give it once per checkpoint, two or more")
    parser.add_argument("--out", required=True, help="where to write the joined checkpoint")
    args = parser.parse_args()
    if len(args.checkpoint) < 2:
        parser.error("--checkpoint: give two or more")
    model, info = mixed(args.checkpoint)
    names = ["/".join(Path(path).parts[-3:]) for path in args.checkpoint]  # no machine's absolute path
    print(f"wrote {save_checkpoint(model, args.out, {**retextured_info(info), 'texture_mixed_from': names})}")


if __name__ == "__main__":
    main()
