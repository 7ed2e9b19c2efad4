"""The demo's page: per row a simulated input, its n translated samples and a real frame, all drawn as fans,
in one self-contained HTML file (sonar_realism.report_html).

Inputs and translations are paired by seq (the translator keeps its input's seq); the first `rows` pairs are
kept, so memory stays bounded however long the stream runs. The real frame comes from a recording given by
path, else from the real Oculus set when the data folder has it (sonar_realism.data); without one the page
says so.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from sonar_realism import plots
from sonar_realism.data import DATA_ENV, OCULUS_HELD_OUT_RECORDING, data_root, oculus_recording_files
from sonar_realism.frames import SonarImage
from sonar_realism.io import read_frames
from sonar_realism.report_html import Figure, Section, Table, Text, write_html


class DemoPage:
    def __init__(self, rows: int = 4, real: str | Path | None = None) -> None:
        self.rows = rows
        self.real = Path(real) if real else None
        self.simulated: dict[int, SonarImage] = {}
        self.translated: dict[int, SonarImage] = {}
        self.counts = {"simulated": 0, "translated": 0}

    def add_simulated(self, frame: SonarImage) -> None:
        self.counts["simulated"] += 1
        if len(self.simulated) < self.rows:
            self.simulated.setdefault(frame.seq, frame)

    def add_translated(self, frame: SonarImage) -> None:
        self.counts["translated"] += 1
        if frame.seq in self.simulated and frame.seq not in self.translated:
            self.translated[frame.seq] = frame

    def real_frames(self) -> tuple[list[SonarImage], str]:
        """(up to `rows` real frames, where they came from) or ([], why not)."""
        if self.real is not None:
            sources = [self.real]
        else:
            sources = oculus_recording_files(OCULUS_HELD_OUT_RECORDING)[: self.rows]
            if not sources:
                return [], f"none: no real recording given and none in the data folder (set {DATA_ENV})"
        frames = [frame for source in sources for frame in itertools.islice(read_frames(source), self.rows)]
        where = str(self.real) if self.real is not None else \
            f"the data folder's {sources[0].parent.relative_to(data_root())} ({OCULUS_HELD_OUT_RECORDING})"
        return frames[: self.rows], where if frames else f"none: {where} holds no frame"

    def write(self, path: str | Path, title: str = "Demo: simulated -> realistic") -> Path:
        path = Path(path)
        reals, real_source = self.real_frames()
        pairs = [(self.simulated[seq], self.translated[seq]) for seq in sorted(self.translated)]
        items: list = [Text(f"Frames seen: {self.counts['simulated']} simulated, {self.counts['translated']} "
                            f"translated. Real frame: {real_source}.")]
        if pairs:
            n_samples = max(output.n_samples for _, output in pairs)
            fans, labels = [], []
            for index, (simulated, output) in enumerate(pairs):
                real = _on_geometry_of(reals[index % len(reals)], simulated) if reals else None
                row = [(simulated, f"simulated, seq {simulated.seq}")]
                row += [(output.sample(i) if output.intensity.ndim == 3 else output, f"sample {i + 1}")
                        for i in range(output.n_samples)]
                row += [(None, "")] * (n_samples - output.n_samples)
                row += [(real, "real" + (" (sim's geometry)" if real.meta.get("geometry_assumed") else ""))] \
                    if real is not None else []
                for frame, label in row:
                    if frame is not None:
                        fans.append((frame.normalized(), frame.ranges_m, frame.azimuths_rad))
                        labels.append(label)
            columns = n_samples + 1 + bool(reals)
            figure = plots.fan_grid(fans, path.with_name(path.stem + "_fans.png"), ncols=columns, labels=labels,
                                    tile_px=240, colorbar_label="intensity (full scale = 1)")
            items.append(Figure(figure, "per row: the simulated input, its translated samples, a real frame (one "
                                        "without geometry in its file is drawn over the simulated frame's span)"))
            provenance = pairs[0][1].meta.get("provenance", {})
            items.append(Table(["provenance", "value"], [[key, value] for key, value in provenance.items()]))
        else:
            items.append(Text("No translated frame arrived, so there is nothing to show side by side."))
        return write_html(path, title, [Section("Simulated input, its samples and a real frame", items)])


def _on_geometry_of(real: SonarImage, simulated: SonarImage) -> SonarImage:
    """A real frame whose file carries no geometry, spread over the simulated frame's range and bearing span."""
    if not real.meta.get("geometry_assumed"):
        return real
    ranges = np.linspace(simulated.ranges_m[0], simulated.ranges_m[-1], real.n_ranges)
    azimuths = np.linspace(simulated.azimuths_rad[0], simulated.azimuths_rad[-1], real.n_beams)
    return real.replace(ranges_m=ranges, azimuths_rad=azimuths)
