"""The `sonar-realism` command. Each subcommand lives beside the code it drives.

A subcommand module exposes `add_arguments(parser)` and `run(args) -> int`; it is imported only
when that subcommand runs, so `sonar-realism inspect` never pays for importing torch.
"""

from __future__ import annotations

import argparse
import importlib
import os
import shlex
import sys

from sonar_realism.data import DATA_ENV
from sonar_realism.errors import SonarRealismError

SUBCOMMANDS = {
    "inspect": ("sonar_realism.io.inspect", "per-frame metadata of any supported recording"),
    "simulate": ("sonar_realism.sim.cli", "simulate sonar frames with a chosen set of real-sensor effects"),
    "calibrate": ("sonar_realism.sim.calibrate", "fit the simulator to a sensor from its recording (CALIB.json)"),
    "train": ("sonar_realism.models.train", "train the cDFCVAE (or the CycleGAN baseline)"),
    "translate": ("sonar_realism.models.translate", "turn simulated frames into n realistic samples each"),
    "evaluate": ("sonar_realism.evaluate.cli", "realism evaluation: Table I and further metrics"),
    "diagnose": ("sonar_realism.diagnose.cli", "sim-to-real gap: where, which effect, how far it shrinks"),
    "launch": ("sonar_realism.runtime.launch", "run a launch file (a graph of streaming nodes)"),
}


def build_parser(argv: list[str]) -> tuple[argparse.ArgumentParser, str | None]:
    parser = argparse.ArgumentParser(prog="sonar-realism", description=__doc__.splitlines()[0])
    parser.add_argument("--data", help=f"the data folder with the real sets (default: ${DATA_ENV}, else "
                                       "../shared/data beside the checkout)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    words = [a for i, a in enumerate(argv) if not a.startswith("-") and (i == 0 or argv[i - 1] != "--data")]
    chosen = words[0] if words else None
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        sp = sub.add_parser(name, help=help_text, description=help_text)
        if name == chosen:
            importlib.import_module(module_name).add_arguments(sp)
    return parser, chosen if chosen in SUBCOMMANDS else None


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser, chosen = build_parser(argv)
    args = parser.parse_args(argv)
    if chosen is None:
        parser.print_help()
        return 2
    # what a run records as its command: as typed, not where this machine installed the program
    args.command_line = "sonar-realism " + shlex.join(argv)
    if args.data:  # one setting for every part that finds the real sets (sonar_realism.data)
        os.environ[DATA_ENV] = args.data
    module = importlib.import_module(SUBCOMMANDS[chosen][0])
    try:
        return int(module.run(args) or 0)
    except SonarRealismError as exc:
        print(f"sonar-realism {chosen}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the reader of our output left (`inspect ... | head`): nothing more to say
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:  # a file the arguments name that the system refused (the message names the file)
        print(f"sonar-realism {chosen}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"sonar-realism {chosen}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
