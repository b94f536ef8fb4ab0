"""``/api/episodes``: the latest evaluation's episodes, with the chosen pose drawn into each frame.

The evaluator writes one MCAP per episode under ``runs/<id>/eval/`` (``v<version>-seed<seed>.mcap``)
before it appends the version's row to ``eval.csv``, so the newest version in eval.csv is the
newest *complete* evaluation (falling back to the newest file version when the CSV is missing).
Each step's executed next-best pose is projected into every camera with that frame's stored
intrinsics and extrinsics (pixel centre of ``(u, v)`` at integer coordinates, as the cameras
define it), together with a 5 cm axis triad of its orientation. Frames are served as PNG.
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
from PIL import Image

from dashboard.filecache import CsvTail, FileCache, stamp
from protocol.episode_file import DemoFileError, EpisodeView, read_episode_view

EPISODE_FILE = re.compile(r"^v(\d{6,})-seed(\d+)\.mcap$")
AXIS_LENGTH_M = 0.05
#: The dashboard's words for why an episode ended (the evaluator's Rollout.reason).
OUTCOMES = ("success", "timeout", "unreachable", "failed")


class EvalEpisodes:
    """The evaluation episodes of one run directory, read on demand and memoised."""

    def __init__(self, run_dir: Path, cache: FileCache | None = None, eval_csv: CsvTail | None = None) -> None:
        self.directory = Path(run_dir) / "eval"
        self.eval_csv = eval_csv or CsvTail(Path(run_dir) / "metrics" / "eval.csv")
        self.cache = cache or FileCache()
        self.views = FileCache(max_entries=24)  #: decoded episode files
        self.pngs = FileCache(max_entries=512)  #: encoded frames

    def files(self) -> dict[int, list[Path]]:
        """Episode files by weights version."""
        out: dict[int, list[Path]] = {}
        try:
            names = [p for p in self.directory.iterdir() if EPISODE_FILE.match(p.name)]
        except OSError:
            return out
        for p in names:
            out.setdefault(int(EPISODE_FILE.match(p.name).group(1)), []).append(p)
        return {v: sorted(ps, key=lambda p: int(EPISODE_FILE.match(p.name).group(2))) for v, ps in out.items()}

    def latest_version(self, files: dict[int, list[Path]]) -> int | None:
        header, rows = self.eval_csv.read()
        if "weights_version" in header:
            i = header.index("weights_version")
            done = [int(r[i]) for r in rows if r[i] is not None and int(r[i]) in files]
            if done:
                return max(done)
        return max(files) if files else None

    def episodes(self) -> tuple[dict, str]:
        """(the /api/episodes body, its ETag)."""
        files = self.files()
        version = self.latest_version(files)
        paths = files.get(version, [])
        return self.cache.for_files(f"episodes-v{version}", [self.eval_csv.path, *paths],
                                    lambda: self._build(version, paths))

    def _build(self, version: int | None, paths: list[Path]) -> dict:
        episodes, errors = [], []
        for path in paths:
            try:
                episodes.append(describe(path, self.view(path), stamp(path)))
            except DemoFileError as e:
                errors.append(f"{path.name}: {e.reason}")
        cameras = episodes[0]["cameras"] if episodes else []
        return {"available": bool(episodes), "weights_version": version, "cameras": cameras,
                "episodes": episodes, "errors": errors}

    def view(self, path: Path) -> EpisodeView:
        return self.views.get(("view", str(path), stamp(path)), lambda: read_episode_view(path))

    def frame_png(self, name: str, camera: str, index: int) -> bytes | None:
        """PNG of frame ``index`` of ``camera`` in episode file ``name``; None if there is no such frame."""
        if not EPISODE_FILE.match(name):
            return None  # only our own file names: no path ever leaves eval/
        path = self.directory / name
        try:
            view = self.view(path)
        except DemoFileError:
            return None
        if camera not in view.rgb or not 0 <= index < view.frames:
            return None
        return self.pngs.get(("png", str(path), stamp(path), camera, index),
                             lambda: encode_png(view.rgb[camera][index]))


def describe(path: Path, view: EpisodeView, file_stamp) -> dict:
    """One episode as JSON: outcome, and per frame its image URLs and the pose chosen there."""
    tag = file_stamp[1] if file_stamp else 0
    frames = []
    for i in range(view.frames):
        action = view.actions[i] if i < len(view.actions) else None
        frames.append({
            "index": i,
            "images": {c: f"api/episodes/frame/{path.name}/{c}/{i}.png?t={tag}" for c in view.cameras},
            "action": None if action is None else [round(float(x), 4) for x in action],
            "pose": None if action is None else {
                c: project_pose(action, view.intrinsics[c][i], view.extrinsics[c][i], view.rgb[c][i].shape[:2])
                for c in view.cameras},
        })
    outcome, reason = outcome_of(view)
    return {"file": path.name, "seed": view.seed, "task": view.task, "success": view.success, "outcome": outcome,
            "reason": reason, "decisions": len(view.actions), "cameras": view.cameras,
            "image_size": list(view.rgb[view.cameras[0]][0].shape[:2]) if view.cameras else None, "frames": frames}


def outcome_of(view: EpisodeView) -> tuple[str, str]:
    """(success | timeout | unreachable | failed | unknown, the control agent's reason for unreachable)."""
    if view.end_reason in OUTCOMES:
        return view.end_reason, view.unreachable_reason if view.end_reason == "unreachable" else ""
    return ("success", "") if view.success else ("unknown", "")  # files written before the end was recorded


def project_pose(action, intrinsics, extrinsics, size) -> dict:
    """Pixel (u, v) of the pose's position and of its 5 cm x/y/z axis tips; ``in_view`` if in front and inside."""
    a = np.asarray(action, np.float64)
    centre, rot = a[:3], quaternion_matrix(a[3:7])
    tips = [centre + AXIS_LENGTH_M * rot[:, k] for k in range(3)]
    uv, depth = project(
        np.stack([centre, *tips]), np.asarray(intrinsics, np.float64), np.asarray(extrinsics, np.float64)
    )
    h, w = size
    u, v = uv[0]
    in_view = bool(depth[0] > 0 and -0.5 <= u < w - 0.5 and -0.5 <= v < h - 0.5)
    pixels = [[round(float(x), 1), round(float(y), 1)] if d > 0 else None for (x, y), d in zip(uv, depth)]
    return {"uv": pixels[0], "axes": pixels[1:], "in_view": in_view}


def project(points: np.ndarray, k: np.ndarray, camera_to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points [N, 3] -> pixels [N, 2] (u right, v down) and depth along the optical axis [N]."""
    world_to_cam = np.linalg.inv(camera_to_world)
    cam = points @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
    uvw = cam @ k.T
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = uvw[:, :2] / np.where(np.abs(uvw[:, 2:3]) > 1e-9, uvw[:, 2:3], np.nan)
    return np.nan_to_num(uv, nan=-1e6, posinf=1e6, neginf=-1e6).clip(-1e6, 1e6), z


def quaternion_matrix(q) -> np.ndarray:
    """Rotation matrix of a quaternion (x, y, z, w); identity for a zero quaternion."""
    x, y, z, w = np.asarray(q, np.float64)
    n = x * x + y * y + z * z + w * w
    if n < 1e-12:
        return np.eye(3)
    s = 2.0 / n
    return np.array([
        [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
        [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
        [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
    ])


def encode_png(rgb: np.ndarray) -> bytes:
    """uint8 [H, W, 3] camera frame -> PNG bytes."""
    image = np.ascontiguousarray(rgb, dtype=np.uint8)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an [H, W, 3] image, got shape {image.shape}")
    out = io.BytesIO()
    Image.fromarray(image, "RGB").save(out, format="PNG")
    return out.getvalue()
