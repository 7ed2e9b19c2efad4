"""`sonar-realism evaluate`: Table I and the further metrics for one or more translators, as JSON + Markdown.

    sonar-realism evaluate --real DIR [--sim DIR ...] --model CKPT [--model CKPT ...] --out DIR

Without --sim the organic and constructed scenes are simulated here (with their object masks, which
the mask-IoU metric needs). A model is a cDFCVAE checkpoint, a CycleGAN one (told apart by the JSON
beside it), or "default" for the shipped cDFCVAE; NAME=CKPT sets the column name.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tqdm import tqdm

from sonar_realism.arguments import non_negative_int, output_folder, positive_int
from sonar_realism.config import from_dict, parse_grid
from sonar_realism.errors import ConfigError
from sonar_realism.evaluate.suite import SimInput, SuiteConfig, Translator
from sonar_realism.frames import SonarImage
from sonar_realism.io import load_recording
from sonar_realism.models.realism_cnn import RealismCNNConfig
from sonar_realism.sim.masks import frames_with_masks


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--real", required=True, help="real frames no translator trained on (folder or recording)")
    parser.add_argument("--sim", action="append", default=[], metavar="DIR",
                        help="simulated frames (repeatable); category = frame meta 'scene', else the folder name")
    parser.add_argument("--scenes", default="organic,constructed",
                        help="scenes to simulate when no --sim is given (default: organic,constructed)")
    parser.add_argument("--n-sim", type=int, default=40, help="frames simulated per scene (default 40)")
    parser.add_argument("--sim-effects", default="none", help="effects of the simulated inputs (default none)")
    parser.add_argument("--model", action="append", default=[], metavar="[NAME=]CKPT",
                        help="translator checkpoint (repeatable); 'default' = the shipped cDFCVAE")
    parser.add_argument("--out", required=True, help="output folder (results.json, report.html, report.md, PNGs)")
    parser.add_argument("--n", type=int, default=4, help="samples per input from each translator (default 4)")
    parser.add_argument("--grid", default="128x128", help="model grid ROWSxCOLS (default 128x128)")
    parser.add_argument("--max-real", type=positive_int, default=None, help="use at most this many real frames")
    parser.add_argument("--yardstick", help="real frames of another recording (e.g. the translators' training "
                                            "one), scored in Table I beside the held-out reference")
    parser.add_argument("--cnn-epochs", type=int, default=RealismCNNConfig.epochs, help="realism CNN epochs")
    parser.add_argument("--seed", type=non_negative_int, default=0)
    parser.add_argument("--device", default="auto", help="torch device for the translators (auto, cpu, cuda or cuda:N)")


def _translator_from_spec(spec: str, device: str) -> tuple[str, Translator, str]:
    """(column name, translator, checkpoint path) of a --model argument: [NAME=]CKPT, CKPT may be "default"."""
    from sonar_realism.models.cyclegan import CycleGANTranslator
    from sonar_realism.models.translate import DEFAULT_CHECKPOINT, load_translator

    name, _, path = spec.rpartition("=")
    if path == "default":
        path = str(DEFAULT_CHECKPOINT)
    if not Path(path).exists():
        raise ConfigError(f"--model: {path}: no such checkpoint")
    translator = load_translator(path, device)
    return name or ("cyclegan" if isinstance(translator, CycleGANTranslator) else "cdfcvae"), translator, path


def _sim_inputs(args: argparse.Namespace) -> list[SimInput]:
    if args.sim:
        items = []
        for folder in args.sim:  # with the object masks `sonar-realism simulate` writes beside its frames
            for frame, mask in tqdm(frames_with_masks(folder), desc=f"read {folder}", unit="frame"):
                items.append(SimInput(frame, str(frame.meta.get("scene") or Path(folder).name), mask))
        return items
    from sonar_realism.sim import simulate

    items = []
    for scene in [s.strip() for s in args.scenes.split(",") if s.strip()]:
        effects = args.sim_effects if args.sim_effects in ("none", "all") else args.sim_effects.split(",")
        for frame, mask in tqdm(simulate(scene=scene, effects=effects, n=args.n_sim, seed=args.seed),
                                desc=f"simulate {scene}", total=args.n_sim, unit="frame"):
            items.append(SimInput(frame, scene, mask))
    return items


def _read_real(path: str, limit: int | None, flag: str) -> list[SonarImage]:
    """The first `limit` real frames of `path` (a data set split into subfolders too)."""
    frames = load_recording(path)[:limit]
    if not frames:
        raise ConfigError(f"{flag} {path}: no frames found (in it or in its subfolders)")
    return frames


def run(args: argparse.Namespace) -> int:
    import torch

    from sonar_realism.evaluate.report import write_report
    from sonar_realism.evaluate.suite import run_suite

    output_folder(args.out, "--out")
    torch.manual_seed(args.seed)
    grid = parse_grid(args.grid)
    config = from_dict(SuiteConfig, {"grid": list(grid), "n_samples": args.n, "seed": args.seed,
                                     "cnn": {"grid": list(grid), "epochs": args.cnn_epochs}})
    translators, paths = {}, {}
    for spec in args.model:
        name, translator, path = _translator_from_spec(spec, args.device)
        if name in translators:
            name = f"{name}-{Path(path).stem}"
        translators[name], paths[name] = translator, path
    real = _read_real(args.real, args.max_real, "--real")
    other = _read_real(args.yardstick, args.max_real, "--yardstick") if args.yardstick else []
    sim = _sim_inputs(args)
    result = run_suite(real, sim, translators, config, log=lambda line: print(line, file=sys.stderr),
                       other_real=other)
    report = write_report(result, args.out, {"real": str(args.real), "yardstick": args.yardstick,
                                             "sim": args.sim or args.scenes,
                                             "models": paths, "command": args.command_line})
    print(f"report: {report}", file=sys.stderr)
    table = result.summary["table"]["all"]
    for name, cell in table.items():
        print(f"{name:>18}: realism {cell['mean']:.3f} [{cell['ci_low']:.3f}, {cell['ci_high']:.3f}]")
    return 0
