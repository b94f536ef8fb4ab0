"""A checkpoint on disk: how a store :class:`Snapshot` is written, verified and read back.

One directory of raw ``.npy`` files plus a JSON manifest. When and what to checkpoint (and
the restore at start) is :mod:`replay_server.checkpointer`'s job.

No pickle, no size ceiling (each array is streamed to its own file, so nothing is ever
concatenated in memory and no container format limits the size). A checkpoint is written
into ``.tmp-ckpt-<seq>``, every file is fsynced, a ``COMPLETE`` marker is written last and
the directory is renamed to ``ckpt-<seq>`` (then the parent is fsynced). Only directories
named ``ckpt-*`` that contain ``COMPLETE`` are ever restored; every file's CRC32 is in the
manifest and is checked on load, and a checkpoint that fails is skipped for an older one.

Layout::

    manifest.json               format, schema, episode metadata, store state, extra, file CRCs
    obs.<name>.npy              [sum(T+1), ...] every episode's observation array, in order
    step.<name>.npy             [sum(T)] / [sum(T), 8] step arrays
    frames.<name>.bin/.idx.npy  compressed frames (concatenated blobs + int64 offsets)
    slots.npy                   [sum(T)] slot of each transition
    priorities.npy, slot_key.npy, free.npy
"""
from __future__ import annotations

import json
import logging
import os
import re
import shutil
import time
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Optional

import numpy as np

from replay_server.storage import Snapshot
from replay_server.stored_episode import STEP_NAMES, StoredEpisode

log = logging.getLogger(__name__)

FORMAT = "c2farm-replay-checkpoint/1"
_NAME = re.compile(r"^ckpt-(\d{8})$")
_CHUNK = 8 << 20


class _CrcFile:
    """A write-only file that keeps a running CRC32 and byte count."""

    def __init__(self, path: Path):
        self._f = open(path, "wb")
        self.crc = 0
        self.nbytes = 0

    def write(self, data) -> int:
        mv = memoryview(data).cast("B") if not isinstance(data, (bytes, bytearray)) else data
        self._f.write(mv)
        self.crc = zlib.crc32(mv, self.crc)
        self.nbytes += len(mv)
        return len(mv)

    def close(self) -> None:
        self._f.flush()
        os.fsync(self._f.fileno())
        self._f.close()


def _raw(a: np.ndarray) -> memoryview:
    return memoryview(np.ascontiguousarray(a).reshape(-1).view(np.uint8))


def _write_npy(path: Path, dtype, shape, parts: Iterable[np.ndarray]) -> dict:
    f = _CrcFile(path)
    try:
        header = {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)), "fortran_order": False, "shape": tuple(shape)}
        np.lib.format.write_array_header_2_0(f, header)
        for part in parts:
            f.write(_raw(part))
    finally:
        f.close()
    return {"crc32": f.crc, "bytes": f.nbytes}


def _file_crc(path: Path) -> int:
    crc = 0
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            crc = zlib.crc32(chunk, crc)
    return crc


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def list_checkpoints(root: Path, complete_only: bool = True) -> list[tuple[int, Path]]:
    root = Path(root)
    if not root.is_dir():
        return []
    found = []
    for p in root.iterdir():
        m = _NAME.match(p.name)
        if m and (not complete_only or (p / "COMPLETE").is_file()):
            found.append((int(m.group(1)), p))
    return sorted(found)


@dataclass
class CheckpointResult:
    path: Path
    bytes: int
    seconds: float


def write_checkpoint(root: Path, snap: Snapshot, keep: int = 2) -> CheckpointResult:
    """Write ``snap`` atomically under ``root`` and delete all but the newest ``keep``."""
    t0 = time.perf_counter()
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    existing = list_checkpoints(root, complete_only=False)
    seq = (existing[-1][0] + 1) if existing else 0
    tmp = root / f".tmp-ckpt-{seq:08d}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    files: dict[str, dict] = {}
    eps = snap.episodes
    try:
        schema = snap.schema or {}
        for name, (dtype, shape) in schema.items():
            if eps and name in eps[0].frames:
                blob = _CrcFile(tmp / f"frames.{name}.bin")
                offsets = [0]
                try:
                    for ep in eps:
                        for b in ep.frames[name]:
                            blob.write(b)
                            offsets.append(offsets[-1] + len(b))
                finally:
                    blob.close()
                files[f"frames.{name}.bin"] = {"crc32": blob.crc, "bytes": blob.nbytes}
                files[f"frames.{name}.idx.npy"] = _write_npy(
                    tmp / f"frames.{name}.idx.npy", np.int64, (len(offsets),), [np.asarray(offsets, np.int64)]
                )
            else:
                rows = sum(ep.num_steps + 1 for ep in eps)
                files[f"obs.{name}.npy"] = _write_npy(
                    tmp / f"obs.{name}.npy", dtype, (rows,) + tuple(shape), (ep.arrays[name] for ep in eps)
                )
        steps = sum(ep.num_steps for ep in eps)
        for name in STEP_NAMES:
            key = "step/" + name
            if eps:
                dtype, tail = eps[0].arrays[key].dtype, eps[0].arrays[key].shape[1:]
            else:
                dtype, tail = np.float32, ()
            files[f"step.{name}.npy"] = _write_npy(
                tmp / f"step.{name}.npy", dtype, (steps,) + tuple(tail), (ep.arrays[key] for ep in eps)
            )
        files["slots.npy"] = _write_npy(tmp / "slots.npy", np.int64, (steps,), (ep.slots for ep in eps))
        for name, arr in (("priorities", snap.priorities), ("slot_key", snap.slot_key), ("free", snap.free)):
            files[f"{name}.npy"] = _write_npy(tmp / f"{name}.npy", arr.dtype, arr.shape, [arr])
        manifest = {
            "format": FORMAT,
            "created": time.time(),
            "compression": snap.compression,
            "schema": None if snap.schema is None else {k: [d, list(s)] for k, (d, s) in snap.schema.items()},
            "episodes": [ep.meta() | {"nbytes": ep.nbytes} for ep in eps],
            "state": snap.state,
            "dedup": snap.dedup,
            "dedup_floor": snap.dedup_floor,
            "extra": snap.extra,
            "files": files,
        }
        with open(tmp / "manifest.json", "w") as f:
            json.dump(manifest, f)
            f.flush()
            os.fsync(f.fileno())
        with open(tmp / "COMPLETE", "w") as f:
            f.write(json.dumps({"manifest_crc32": _file_crc(tmp / "manifest.json")}))
            f.flush()
            os.fsync(f.fileno())
        _fsync_dir(tmp)
        final = root / f"ckpt-{seq:08d}"
        os.rename(tmp, final)
        _fsync_dir(root)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    for _, old in list_checkpoints(root, complete_only=False)[:-max(1, keep)]:
        shutil.rmtree(old, ignore_errors=True)
    total = sum(v["bytes"] for v in files.values())
    return CheckpointResult(final, total, time.perf_counter() - t0)


def load_checkpoint(path: Path) -> Snapshot:
    """Read and verify one checkpoint directory (raises ValueError if anything is off)."""
    path = Path(path)
    if not (path / "COMPLETE").is_file():
        raise ValueError(f"{path}: no COMPLETE marker")
    marker = json.loads((path / "COMPLETE").read_text())
    if _file_crc(path / "manifest.json") != marker["manifest_crc32"]:
        raise ValueError(f"{path}: manifest CRC mismatch")
    manifest = json.loads((path / "manifest.json").read_text())
    if manifest.get("format") != FORMAT:
        raise ValueError(f"{path}: unknown format {manifest.get('format')!r}")
    for name, info in manifest["files"].items():
        if _file_crc(path / name) != info["crc32"]:
            raise ValueError(f"{path}: {name} CRC mismatch (corrupt file)")

    def npy(name: str) -> np.ndarray:
        return np.load(path / name, mmap_mode="r", allow_pickle=False)

    schema = manifest["schema"]
    schema = None if schema is None else {k: (d, tuple(s)) for k, (d, s) in schema.items()}
    metas = manifest["episodes"]
    obs_files, frame_files = {}, {}
    for name in schema or {}:
        if f"frames.{name}.bin" in manifest["files"]:
            frame_files[name] = (
                np.memmap(path / f"frames.{name}.bin", dtype=np.uint8, mode="r")
                if manifest["files"][f"frames.{name}.bin"]["bytes"]
                else np.zeros(0, np.uint8),
                np.load(path / f"frames.{name}.idx.npy", allow_pickle=False),
            )
        else:
            obs_files[name] = npy(f"obs.{name}.npy")
    step_files = {name: npy(f"step.{name}.npy") for name in STEP_NAMES}
    slots_all = np.load(path / "slots.npy", allow_pickle=False)
    episodes = []
    row = step = frame = 0
    for m in metas:
        t = int(m["num_steps"])
        arrays = {name: np.array(a[row : row + t + 1]) for name, a in obs_files.items()}
        frames = {}
        for name, (blob, idx) in frame_files.items():
            frames[name] = [bytes(blob[idx[i] : idx[i + 1]]) for i in range(frame, frame + t + 1)]
        for name, a in step_files.items():
            arrays["step/" + name] = np.array(a[step : step + t])
        episodes.append(
            StoredEpisode(
                serial=int(m["serial"]),
                actor_id=m["actor_id"],
                episode_id=int(m["episode_id"]),
                task=m["task"],
                seed=int(m["seed"]),
                is_demo=bool(m["is_demo"]),
                success=bool(m["success"]),
                timeout=bool(m["timeout"]),
                info=dict(m["info"]),
                num_steps=t,
                arrays=arrays,
                frames=frames,
                slots=np.array(slots_all[step : step + t]),
                nbytes=int(m["nbytes"]),
            )
        )
        row += t + 1
        frame += t + 1
        step += t
    return Snapshot(
        episodes=episodes,
        schema=schema,
        compression=manifest["compression"],
        priorities=np.load(path / "priorities.npy", allow_pickle=False),
        slot_key=np.load(path / "slot_key.npy", allow_pickle=False),
        free=np.load(path / "free.npy", allow_pickle=False),
        state=manifest["state"],
        dedup={a: list(ids) for a, ids in manifest["dedup"].items()},
        dedup_floor={a: int(v) for a, v in manifest["dedup_floor"].items()},
        extra=manifest["extra"],
    )


def load_latest(root: Path) -> Optional[tuple[Path, Snapshot]]:
    """The newest checkpoint that loads and verifies; corrupt ones are logged and skipped."""
    for _, path in reversed(list_checkpoints(root)):
        try:
            return path, load_checkpoint(path)
        except Exception as exc:  # a bad checkpoint must not stop the server: try an older one
            log.error("checkpoint %s cannot be restored (%s); trying an older one", path, exc)
    return None
