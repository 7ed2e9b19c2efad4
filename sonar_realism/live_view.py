"""A live view for Foxglove: frames as fan images and node status, served over the Foxglove WebSocket protocol
(the `foxglove-sdk` package; its server speaks the `foxglove.sdk.v1` subprotocol) on localhost.

    view = LiveView(port=8765)               # Foxglove: Open connection -> ws://localhost:8765
    view.show("/sonar/translated", frame)     # a foxglove.CompressedImage (PNG) of the fan, at the frame's stamp
    view.status({"node": "viewer", ...})      # JSON on /viewer/status

Every frame is drawn when it is shown (the stream's own rate); a multi-sample frame shows its first
`max_samples` samples side by side. Socket-free drawing (`fan_png`) is separate so it can be tested alone.
"""

from __future__ import annotations

import time
from typing import Any

import cv2
import numpy as np

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage
from sonar_realism.geometry import polar_to_fan

STATUS_TOPIC = "/viewer/status"
_LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")


def fan_png(frame: SonarImage, width_px: int = 480, max_samples: int = 4) -> bytes:
    """The frame as a fan (apex at the bottom, inferno colours, black outside), PNG bytes; samples side by side."""
    planes = [frame.sample(i) for i in range(min(frame.n_samples, max_samples))] if frame.intensity.ndim == 3 \
        else [frame]
    fans = [polar_to_fan(plane.replace(intensity=plane.normalized()), width_px) for plane in planes]
    grey = np.clip(np.rint(np.hstack(fans) * 255.0), 0, 255).astype(np.uint8)
    coloured = cv2.applyColorMap(grey, cv2.COLORMAP_INFERNO)
    coloured[grey == 0] = 0
    ok, encoded = cv2.imencode(".png", coloured)
    if not ok:
        raise ValueError("fan_png: PNG encoding failed")
    return encoded.tobytes()


class LiveView:
    """A Foxglove WebSocket server on this host with one image channel per topic shown and a status channel."""

    def __init__(self, host: str = "127.0.0.1", port: int = 8765, width_px: int = 480, max_samples: int = 4,
                 name: str = "sonar-realism") -> None:
        import foxglove

        if host not in _LOCAL_HOSTS:
            raise ConfigError(f"viewer: host {host!r} is not this machine; the live view serves localhost only")
        self.width_px, self.max_samples = width_px, max_samples
        self._foxglove = foxglove
        self.context = foxglove.Context()  # our own: channels and server of this view only
        self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context)
        self._images: dict[str, Any] = {}
        self._status = foxglove.Channel(STATUS_TOPIC, message_encoding="json", context=self.context)
        self.shown = 0

    @property
    def port(self) -> int:
        return int(self.server.port)

    def show(self, topic: str, frame: SonarImage) -> None:
        from foxglove.channels import CompressedImageChannel
        from foxglove.messages import CompressedImage, Timestamp

        channel = self._images.get(topic)
        if channel is None:
            channel = self._images[topic] = CompressedImageChannel(topic, context=self.context)
        stamp_ns = frame.stamp_ns or time.time_ns()
        seconds, nanoseconds = divmod(stamp_ns, 1_000_000_000)
        message = CompressedImage(timestamp=Timestamp(seconds, nanoseconds), frame_id=frame.frame_id,
                                  data=fan_png(frame, self.width_px, self.max_samples), format="png")
        channel.log(message, log_time=stamp_ns)
        self.shown += 1

    def status(self, status: dict[str, Any]) -> None:
        self._status.log(status)

    def close(self) -> None:
        self.server.stop()
