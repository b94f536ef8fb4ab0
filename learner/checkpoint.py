"""Atomic learner checkpoints: tensors in safetensors, everything else in JSON. No pickle.

A checkpoint is a directory ``step-<N>/`` holding ``tensors.safetensors``, ``state.json``
and a ``COMPLETE`` marker, written under a temporary name, fsynced and renamed, so a crash
mid-write leaves the previous checkpoint intact and the half-written one ignored.

Non-finite numbers never go into a checkpoint or come out of one: :func:`save_checkpoint`
refuses such a state (:class:`NonFiniteState`, previous checkpoints kept), and
:func:`load_latest` passes over a checkpoint that holds them (or cannot be read) for the
previous complete one, so a poisoned state cannot survive a restart.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

MARKER = "COMPLETE"
log = logging.getLogger(__name__)


class NonFiniteState(ValueError):
    """A state holding NaN or inf: checkpointing it would make resuming useless."""


def flatten_state(state: Any, prefix: str = "") -> tuple[dict[str, torch.Tensor], Any]:
    """Split a nested state (dicts/lists of tensors and plain values) into tensors + a JSON skeleton.

    Each tensor is replaced in the skeleton by ``{"__tensor__": name}``; integer dict keys
    (as in optimiser states) are kept via ``{"__int_keys__": ...}``.
    """
    tensors: dict[str, torch.Tensor] = {}

    def walk(node: Any, path: str) -> Any:
        if isinstance(node, torch.Tensor):
            tensors[path] = node.detach().cpu().contiguous()
            return {"__tensor__": path}
        if isinstance(node, dict):
            int_keys = all(isinstance(k, int) for k in node) and bool(node)
            items = {str(k): walk(v, f"{path}.{k}" if path else str(k)) for k, v in node.items()}
            return {"__int_keys__": items} if int_keys else items
        if isinstance(node, (list, tuple)):
            return [walk(v, f"{path}.{i}") for i, v in enumerate(node)]
        if node is None or isinstance(node, (bool, int, float, str)):
            return node
        raise TypeError(f"cannot checkpoint {type(node).__name__} at {path!r}")

    return tensors, walk(state, prefix)


def unflatten_state(tensors: dict[str, torch.Tensor], skeleton: Any) -> Any:
    """Inverse of :func:`flatten_state`."""
    if isinstance(skeleton, dict):
        if set(skeleton) == {"__tensor__"}:
            return tensors[skeleton["__tensor__"]]
        if set(skeleton) == {"__int_keys__"}:
            return {int(k): unflatten_state(tensors, v) for k, v in skeleton["__int_keys__"].items()}
        return {k: unflatten_state(tensors, v) for k, v in skeleton.items()}
    if isinstance(skeleton, list):
        return [unflatten_state(tensors, v) for v in skeleton]
    return skeleton


def save_checkpoint(root: Path, step: int, state: Any, keep: int = 2) -> Path:
    """Write ``state`` atomically as ``root/step-<step>`` and prune all but the newest ``keep``.

    Raises :class:`NonFiniteState` (writing nothing) when a tensor or float holds NaN or inf.
    """
    root = Path(root)
    tensors, skeleton = flatten_state(state)
    bad = nonfinite_tensors(tensors)
    if bad:
        raise NonFiniteState(f"non-finite values in {len(bad)} tensors, e.g. {bad[0]}: checkpoint {step} not written")
    try:
        skeleton_json = json.dumps(skeleton, allow_nan=False)
    except ValueError:
        raise NonFiniteState(f"a non-finite float in the state: checkpoint {step} not written") from None
    root.mkdir(parents=True, exist_ok=True)
    final = root / f"step-{step:09d}"
    tmp = root / f".tmp-step-{step:09d}-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    save_file(tensors, str(tmp / "tensors.safetensors"))
    (tmp / "state.json").write_text(skeleton_json)
    (tmp / MARKER).write_text(str(step))
    for path in tmp.iterdir():
        _fsync(path)
    shutil.rmtree(final, ignore_errors=True)
    os.replace(tmp, final)
    _fsync(root)
    for old in complete_checkpoints(root)[:-keep]:
        shutil.rmtree(old, ignore_errors=True)
    return final


def nonfinite_tensors(tensors: dict[str, torch.Tensor]) -> list[str]:
    """Names of the floating-point tensors that hold NaN or inf."""
    return [name for name, t in tensors.items() if t.is_floating_point() and not bool(torch.isfinite(t).all())]


def complete_checkpoints(root: Path) -> list[Path]:
    """Checkpoint directories that finished writing, oldest first."""
    root = Path(root)
    if not root.is_dir():
        return []
    return sorted(p for p in root.glob("step-*") if (p / MARKER).is_file())


def load_latest(root: Path, device: str | torch.device = "cpu") -> Any | None:
    """The state of the newest complete checkpoint that reads back whole and finite, or None.

    A checkpoint that fails (unreadable, or NaN/inf inside, e.g. written before this check
    existed) is logged and skipped for the one before it.
    """
    for path in reversed(complete_checkpoints(root)):
        try:
            return load_checkpoint(path, device)
        except UNREADABLE as exc:
            log.error("skipping checkpoint %s: %s", path.name, exc)
    return None


#: what reading a damaged checkpoint folder raises
UNREADABLE = (OSError, ValueError, KeyError, TypeError, SafetensorError)


def load_checkpoint(path: Path, device: str | torch.device = "cpu") -> Any:
    """The state in one checkpoint folder (``step-N``); one of :data:`UNREADABLE` if it does not read back whole
    and finite (:class:`NonFiniteState` for NaN/inf)."""
    tensors = load_file(str(path / "tensors.safetensors"), device=str(device))
    skeleton = json.loads((path / "state.json").read_text(), parse_constant=_no_nonfinite)
    state = unflatten_state(tensors, skeleton)
    bad = nonfinite_tensors(tensors)
    if bad:
        raise NonFiniteState(f"non-finite values in {len(bad)} tensors, e.g. {bad[0]}")
    return state


def _no_nonfinite(name: str):
    raise ValueError(f"state.json holds {name}")


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
