"""An exported policy: a folder with ``model.safetensors`` and ``config.json``, nothing else.

What acting needs and no more: the online networks of the cascade (``net.{depth}.{param}``,
as ``C2FARM.weights()`` names them: no target networks, no optimiser) and a JSON config
naming the Q-attention config, cameras, scene bounds, task, weights version, learner step
and code version. Tensors stay in safetensors and facts in JSON, so reading a policy runs no
code from it (no pickle). Both files are written under a temporary name and renamed, so a
crash mid-export leaves no half file behind a complete name.

Everything read is checked before use: a missing, unreadable or inconsistent file is one
:class:`PolicyFileError` line naming the file and what is wrong.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

MODEL = "model.safetensors"
CONFIG = "config.json"
FORMAT = "c2farm-policy"
FORMAT_VERSION = 1
#: config.json keys a reader relies on (writers may add more)
REQUIRED = {"format": str, "format_version": int, "task": str, "cameras": list, "scene_bounds": list,
            "qattention": dict, "network_digest": str, "weights_version": int, "learner_step": int, "code": dict}


class PolicyFileError(ValueError):
    """A policy folder that cannot be used as it is; the message is one line."""


@dataclass
class PolicyFile:
    """A policy as read from (or about to be written to) its folder."""

    tensors: dict[str, torch.Tensor]  #: the online networks, ``net.{depth}.{param}``
    config: dict[str, Any]  #: config.json: see :data:`REQUIRED`

    @property
    def task(self) -> str:
        return self.config["task"]

    @property
    def version(self) -> int:
        return self.config["weights_version"]

    @property
    def learner_step(self) -> int:
        return self.config["learner_step"]


def write_policy(directory: Path, policy: PolicyFile) -> Path:
    """Write ``policy`` into ``directory`` (created); refuses non-finite tensors or a config missing a field."""
    directory = Path(directory)
    config = {"format": FORMAT, "format_version": FORMAT_VERSION, **policy.config}
    _check_config(config, directory / CONFIG)
    _check_tensors(policy.tensors, directory / MODEL)
    directory.mkdir(parents=True, exist_ok=True)
    tensors = {name: t.detach().cpu().contiguous() for name, t in policy.tensors.items()}
    _atomic(directory / MODEL, lambda tmp: save_file(tensors, str(tmp), metadata={"format": FORMAT}))
    text = json.dumps(config, indent=2, allow_nan=False) + "\n"
    _atomic(directory / CONFIG, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    return directory


def read_policy(directory: Path) -> PolicyFile:
    """The policy in ``directory``, checked; raises :class:`PolicyFileError` (one line) when it cannot be used."""
    directory = Path(directory)
    if not directory.is_dir():
        raise PolicyFileError(f"{directory}: not a policy folder (expected {MODEL} and {CONFIG}; "
                              "make one with `c2farm export policy RUN_DIR --out DIR`)")
    for name in (CONFIG, MODEL):
        if not (directory / name).is_file():
            raise PolicyFileError(f"{directory / name}: missing (a policy folder holds {MODEL} and {CONFIG})")
    path = directory / CONFIG
    try:
        config = json.loads(path.read_text(encoding="utf-8"), parse_constant=_no_nonfinite)
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise PolicyFileError(f"{path}: not readable JSON ({_one_line(exc)})") from None
    _check_config(config, path)
    path = directory / MODEL
    try:
        tensors = load_file(str(path))
    except (OSError, SafetensorError, ValueError) as exc:
        raise PolicyFileError(f"{path}: not a readable safetensors file ({_one_line(exc)})") from None
    _check_tensors(tensors, path)
    return PolicyFile(tensors, config)


def _check_config(config: Any, path: Path) -> None:
    if not isinstance(config, dict):
        raise PolicyFileError(f"{path}: expected a JSON object, got {type(config).__name__}")
    if config.get("format") != FORMAT:
        raise PolicyFileError(f"{path}: not a c2farm policy (format {config.get('format')!r}, expected {FORMAT!r})")
    for key, kind in REQUIRED.items():
        value = config.get(key)
        if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
            raise PolicyFileError(f"{path}: field {key!r} must be {kind.__name__}, got {value!r:.60}")
    bounds = config["scene_bounds"]
    if len(bounds) != 6 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                                   for v in bounds):
        raise PolicyFileError(f"{path}: field 'scene_bounds' must be 6 finite numbers, got {bounds!r:.80}")
    if not config["cameras"] or not all(isinstance(c, str) for c in config["cameras"]):
        raise PolicyFileError(f"{path}: field 'cameras' must name at least one camera, got {config['cameras']!r:.80}")
    if config["format_version"] > FORMAT_VERSION:
        raise PolicyFileError(f"{path}: format version {config['format_version']} is newer than this c2farm reads "
                              f"({FORMAT_VERSION}); update c2farm")


def _check_tensors(tensors: dict[str, torch.Tensor], path: Path) -> None:
    if not tensors:
        raise PolicyFileError(f"{path}: holds no tensors")
    odd = next((name for name in tensors if not name.startswith("net.")), None)
    if odd is not None:
        raise PolicyFileError(f"{path}: tensor {odd!r} is not an online network's (net.*)")
    bad = next((n for n, t in tensors.items() if t.is_floating_point() and not bool(torch.isfinite(t).all())), None)
    if bad is not None:
        raise PolicyFileError(f"{path}: tensor {bad!r} holds NaN or inf")


def _atomic(path: Path, write) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        write(tmp)
        os.chmod(tmp, 0o644)  # a policy is meant to be copied and shared; safetensors writes 0600
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _no_nonfinite(name: str):
    raise ValueError(f"{name} is not a number JSON allows")


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())[:200] or type(exc).__name__

