"""An Intel RealSense RGB-D camera through pyrealsense2, with the stand-in camera's contract.

Depth is aligned to the colour stream on the device side (``rs.align``), intrinsics are read
from the colour stream's profile, depth units from the depth sensor, and world points come
from the camera-to-base extrinsics (a YAML file, see ``cameras.py``). The image is centre-
cropped to a square and resampled to ``image_size`` (``cameras.square_frame``).

Not testable without a device: kept small, every step named after the SDK call it uses.
"""

from __future__ import annotations

import numpy as np

from actors.robot.cameras import square_frame
from protocol.observation import CameraFrame


class RealSenseCamera:
    """One RealSense device streaming colour + aligned depth."""

    def __init__(self, name: str, extrinsics: np.ndarray, serial: str = "", image_size: int = 128,
                 width: int = 640, height: int = 480, fps: int = 30) -> None:
        import pyrealsense2 as rs

        self.name, self.extrinsics, self.image_size = name, np.asarray(extrinsics, dtype=float), image_size
        self._pipeline = rs.pipeline()
        config = rs.config()
        if serial:
            config.enable_device(serial)
        config.enable_stream(rs.stream.color, width, height, rs.format.rgb8, fps)
        config.enable_stream(rs.stream.depth, width, height, rs.format.z16, fps)
        profile = self._pipeline.start(config)
        self._align = rs.align(rs.stream.color)
        self._depth_scale = profile.get_device().first_depth_sensor().get_depth_scale()  # metres per unit
        i = profile.get_stream(rs.stream.color).as_video_stream_profile().get_intrinsics()
        self.intrinsics = np.array([[i.fx, 0.0, i.ppx], [0.0, i.fy, i.ppy], [0.0, 0.0, 1.0]])
        self._running = True

    def capture(self) -> CameraFrame:
        frames = self._align.process(self._pipeline.wait_for_frames())
        rgb = np.asanyarray(frames.get_color_frame().get_data())
        depth = np.asanyarray(frames.get_depth_frame().get_data()).astype(np.float32) * self._depth_scale
        return square_frame(rgb, depth, self.intrinsics, self.extrinsics, self.image_size)

    def close(self) -> None:
        if self._running:
            self._running = False
            self._pipeline.stop()
