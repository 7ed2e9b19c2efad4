"""Split the ARIS water-tank set (../shared/data/real/marine_debris_watertank) into a fit set and a held-out set.

The set's files carry no recording names (their counters interleave the recordings), but its frames come in two
fan geometries, one per recording setting: apex at 602 px, the full 30 deg fan out to 5.8 m (1109 frames), and apex
at 749 px, a 24.3 deg fan out to 7.2 m (759 frames). They stand in for recordings: fit on the first, test on the
second. Writes two folders of symbolic
links (never copies of the unlicensed data):

    python scripts/aris_split.py --out runs/aris     ->  runs/aris/fit/ (30 deg), runs/aris/heldout/ (24.3 deg)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sonar_realism.data import real_aris_dir  # noqa: E402
from sonar_realism.io import read_frames  # noqa: E402

APEX_SPLIT_PX = 675.0  # between the two settings' apex rows (602 and 749)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--data", help="data folder (default: SONAR_REALISM_DATA or ../shared/data)")
    args = parser.parse_args()
    images = real_aris_dir(args.data) / "Images"
    counts = {"fit": 0, "heldout": 0}
    for name in counts:
        (Path(args.out) / name).mkdir(parents=True, exist_ok=True)
    for frame in read_frames(images):
        part = "fit" if frame.meta["fan_apex_px"][1] < APEX_SPLIT_PX else "heldout"
        link = Path(args.out) / part / frame.meta["source"]
        if not link.exists():
            link.symlink_to((images / frame.meta["source"]).resolve())
        counts[part] += 1
    print(f"fit: {counts['fit']} frames, held out: {counts['heldout']} frames -> {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
