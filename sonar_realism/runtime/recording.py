"""Recording a stream: every frame written losslessly as it arrives, plus a contact sheet a person can look at.

Frames go to `sonar_realism.io.write_frames` (a frames folder; NPZ or a ROS 2 MCAP bag when the path ends
in .npz or .mcap) through a writer thread, so disk time never stalls the node's socket loop and only
`max_backlog` frames are held in memory. The contact sheet keeps an evenly spread subset of the stream
without knowing its length: every k-th frame, with k doubling whenever the sheet is full.
"""

from __future__ import annotations

import json
import queue
import threading
from pathlib import Path
from typing import Any

import numpy as np

from sonar_realism.errors import FrameError
from sonar_realism.frames import SonarImage
from sonar_realism.geometry import polar_to_fan
from sonar_realism.io import write_frames
from sonar_realism.io.common import json_default
from sonar_realism.io.folder import is_frames_folder, last_seq, listed_frames, write_frames_folder
from sonar_realism.plots import image_grid

_END = object()


class Recording:
    def __init__(self, path: str | Path, contact_sheet: str | Path | None = None, sheet_tiles: int = 16,
                 samples_per_tile: int = 4, fan_width_px: int = 320, max_backlog: int = 64,
                 resume: bool = False) -> None:
        """`resume`: a frames folder already at `path` (this recorder's, before a restart) is gone on with: new
        frames are added after it, and frames it already holds (seq up to its last one: sent again over a lossless
        edge) are skipped and counted in `already_written`. An NPZ or MCAP file is written anew."""
        self.path = Path(path)
        self._append = resume and is_frames_folder(self.path)
        self._written_through = last_seq(self.path) if self._append else None
        self._before = listed_frames(self.path) if self._append else 0
        self.already_written = 0
        self.contact_sheet = Path(contact_sheet) if contact_sheet else None
        self.sheet_tiles = sheet_tiles
        self.samples_per_tile = samples_per_tile
        self.fan_width_px = fan_width_px
        self.count = 0
        self._kept: list[SonarImage] = []
        self._stride = 1
        self._backlog: queue.Queue[Any] = queue.Queue(maxsize=max_backlog)
        self._error: BaseException | None = None
        self._written = 0
        self._closed = False
        self._writer = threading.Thread(target=self._write, name=f"recorder:{self.path.name}", daemon=True)
        self._writer.start()

    @staticmethod
    def _check(frame: SonarImage) -> None:
        """FrameError if `frame` cannot be written (its meta is not JSON-able): checked before a frame is queued,
        so one bad frame is refused alone instead of stopping the writer and every frame after it."""
        try:
            json.dumps(frame.meta, default=json_default, allow_nan=False)
        except (TypeError, ValueError) as error:
            raise FrameError(f"meta: frame seq {frame.seq} meta is not JSON-able ({error})") from error

    def add(self, frame: SonarImage) -> None:
        self.add_batch([frame])

    def add_batch(self, frames: list[SonarImage]) -> None:
        """Every frame of `frames`, or none of them: each is checked before any is queued (a node retries a batch
        that failed frame by frame, and must not write a frame twice)."""
        self._raise_writer_error()
        for frame in frames:
            self._check(frame)
        for frame in frames:
            self._queue(frame)

    def _queue(self, frame: SonarImage) -> None:
        if self._written_through is not None and frame.seq <= self._written_through:
            self.already_written += 1
            return
        # Received frames are views over ZeroMQ buffers: copy once so the writer owns what it holds.
        frame = frame.replace(intensity=np.array(frame.intensity))
        self._backlog.put(frame)
        if self.count % self._stride == 0:
            self._kept.append(frame)
            if len(self._kept) > self.sheet_tiles:
                self._kept = self._kept[::2]
                self._stride *= 2
        self.count += 1

    def close(self) -> dict[str, Any]:
        """Finish writing (waits for the backlog) and draw the contact sheet; returns a summary."""
        if not self._closed:
            self._closed = True
            self._backlog.put(_END)
            self._writer.join()
            self._raise_writer_error()
            if self.contact_sheet is not None and self._kept:
                self.draw_contact_sheet(self.contact_sheet)
        return {"frames": self._before + self._written, "path": str(self.path),
                "contact_sheet": str(self.contact_sheet) if self.contact_sheet and self._kept else None}

    def draw_contact_sheet(self, path: Path) -> Path:
        tiles, labels = [], []
        for frame in self._kept:
            samples = [frame.sample(i) for i in range(min(frame.n_samples, self.samples_per_tile))] \
                if frame.intensity.ndim == 3 else [frame]
            fans = [polar_to_fan(s.replace(intensity=s.normalized()), self.fan_width_px) for s in samples]
            tiles.append(np.hstack(fans))
            labels.append(f"seq {frame.seq}" + (f"  {frame.n_samples} samples" if frame.n_samples > 1 else ""))
        ncols = 2 if any(frame.n_samples > 1 for frame in self._kept) else 4  # multi-sample tiles are wide
        return image_grid(tiles, path, ncols=ncols, labels=labels)

    def _write(self) -> None:
        try:
            frames = iter(self._backlog.get, _END)
            self._written = (write_frames_folder(frames, self.path, append=True) if self._append
                             else write_frames(frames, self.path))
        except BaseException as error:  # surfaced in the node's thread by add()/close()
            self._error = error
            while self._backlog.get() is not _END:  # keep add() from blocking on a dead writer
                pass

    def _raise_writer_error(self) -> None:
        if self._error is not None:
            raise self._error
