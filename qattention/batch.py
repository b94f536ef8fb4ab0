"""Torch views of what actors observe and what the replay server serves.

Replay batches are dicts of named numpy arrays, named by ``protocol.transition``: the observation
arrays (``{cam}_rgb``, ``{cam}_points``, ``{cam}_intrinsics``, ``{cam}_extrinsics``,
``gripper_pose``, ``gripper_open``, ``finger_positions``, ``step``), the next observation's under
the same names + ``_tp1``, and the step fields (``action``, ``reward``, ``terminal``,
``is_demo``, ``weights``, ``policy_version``). Optional: ``extra_scene_bounds`` [B, 6] (each
row's depth-0 box; else the config's), the act-time labels ``extra_voxel_indices`` [B, D, 3],
``extra_attention_coordinates`` [B, D, 3], ``extra_rot_grip_indices`` [B, 4] returned by ``act``
(used for non-demo rows when present; demo rows are always relabelled), and, for n-step
transitions, ``n_rewards`` [B, n] and ``bootstrap_steps`` [B] (the next observation is then
``bootstrap_steps`` decisions later).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from protocol import transition as tr

from .proprioception import proprioception

#: Each row's depth-0 box, an observation extra (the robot's box differs from the simulator's).
SCENE_BOUNDS = tr.extra_name(tr.SCENE_BOUNDS)


def _t(x, device, dtype=None) -> torch.Tensor:
    t = torch.as_tensor(np.ascontiguousarray(x), device=device)
    return t.to(dtype) if dtype is not None else t


@dataclass
class ObservationBatch:
    rgb: dict[str, torch.Tensor]  #: uint8 [B, H, W, 3] per camera
    points: dict[str, torch.Tensor]  #: float32 [B, H, W, 3] world frame per camera
    intrinsics: dict[str, torch.Tensor]  #: float32 [B, 3, 3] per camera
    extrinsics: dict[str, torch.Tensor]  #: float32 [B, 4, 4] camera-to-world per camera
    gripper_pose: torch.Tensor  #: float32 [B, 7]
    gripper_open: torch.Tensor  #: float32 [B]
    finger_positions: torch.Tensor  #: float32 [B, 2]
    step: torch.Tensor  #: float32 [B], decisions taken before this observation
    scene_bounds: torch.Tensor | None = None  #: float32 [B, 6] or None (use the config's)

    @property
    def size(self) -> int:
        return self.gripper_pose.shape[0]

    @property
    def device(self) -> torch.device:
        return self.gripper_pose.device

    def proprioception(self, config) -> torch.Tensor:
        """[B, 11] low-dim state of spec §1, its time value as ``config`` (a QAttentionConfig) says."""
        return proprioception(self.gripper_open, self.gripper_pose, self.finger_positions, self.step,
                              config.episode_length, config.time_feature)

    def bounds(self, default) -> torch.Tensor:
        """Depth-0 bounds [B, 6]: per-sample if the batch carries them, else ``default``."""
        if self.scene_bounds is not None:
            return self.scene_bounds
        return torch.as_tensor(default, dtype=torch.float32, device=self.device).expand(self.size, 6)

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], cameras, device="cpu", suffix: str = "") -> "ObservationBatch":
        f32 = torch.float32
        g = lambda k, dtype=f32: _t(arrays[k + suffix], device, dtype)  # noqa: E731
        sb = arrays.get(SCENE_BOUNDS + suffix, arrays.get(SCENE_BOUNDS))
        return cls(
            rgb={c: g(f"{c}_rgb", torch.uint8) for c in cameras},
            points={c: g(f"{c}_points") for c in cameras},
            intrinsics={c: g(f"{c}_intrinsics") for c in cameras},
            extrinsics={c: g(f"{c}_extrinsics") for c in cameras},
            gripper_pose=g("gripper_pose"),
            gripper_open=g("gripper_open").reshape(-1),
            finger_positions=g("finger_positions"),
            step=g("step").reshape(-1),
            scene_bounds=None if sb is None else _t(sb, device, f32),
        )

    @classmethod
    def from_observations(cls, observations, cameras, device="cpu", scene_bounds=None) -> "ObservationBatch":
        """Stack ``protocol.observation.Observation`` objects (what an actor holds) into a batch."""
        arrays: dict[str, np.ndarray] = {}
        for c in cameras:
            frames = [o.cameras[c] for o in observations]
            arrays[f"{c}_rgb"] = np.stack([f.rgb for f in frames])
            arrays[f"{c}_points"] = np.stack([f.points for f in frames])
            arrays[f"{c}_intrinsics"] = np.stack([f.intrinsics for f in frames])
            arrays[f"{c}_extrinsics"] = np.stack([f.extrinsics for f in frames])
        arrays["gripper_pose"] = np.stack([o.gripper_pose for o in observations])
        arrays["gripper_open"] = np.array([o.gripper_open for o in observations], np.float32)
        arrays["finger_positions"] = np.stack([o.finger_positions for o in observations])
        arrays["step"] = np.array([o.step for o in observations], np.float32)
        if scene_bounds is not None:
            arrays[SCENE_BOUNDS] = np.broadcast_to(np.asarray(scene_bounds, np.float32), (len(observations), 6))
        return cls.from_arrays(arrays, cameras, device)


@dataclass
class TransitionBatch:
    obs: ObservationBatch
    next_obs: ObservationBatch
    action: torch.Tensor  #: float32 [B, 8] executed pose (xyz, quat xyzw, gripper_open)
    reward: torch.Tensor  #: float32 [B]
    terminal: torch.Tensor  #: bool [B] (timeouts included, as the reference)
    is_demo: torch.Tensor  #: bool [B]
    weights: torch.Tensor  #: float32 [B] importance weights, normalised by the replay server
    policy_version: torch.Tensor | None = None  #: int64 [B]
    voxel_indices: torch.Tensor | None = None  #: long [B, D, 3] act-time choices (optional)
    attention_coordinates: torch.Tensor | None = None  #: float32 [B, D, 3] act-time cube centres (optional)
    rot_grip_indices: torch.Tensor | None = None  #: long [B, 4] act-time bins (optional)
    #: float32 [B, n] rewards of an n-step transition, zero past its end (optional)
    n_rewards: torch.Tensor | None = None
    bootstrap_steps: torch.Tensor | None = None  #: long [B] decisions from obs to next_obs, 1..n (optional)
    extras: dict[str, torch.Tensor] = field(default_factory=dict)

    @property
    def size(self) -> int:
        return self.action.shape[0]

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], cameras, device="cpu") -> "TransitionBatch":
        b = len(arrays[tr.ACTION])
        opt = lambda k, dtype: _t(arrays[k], device, dtype) if k in arrays else None  # noqa: E731
        weights = arrays.get(tr.WEIGHTS)
        return cls(
            obs=ObservationBatch.from_arrays(arrays, cameras, device),
            next_obs=ObservationBatch.from_arrays(arrays, cameras, device, suffix=tr.NEXT),
            action=_t(arrays[tr.ACTION], device, torch.float32),
            reward=_t(arrays[tr.REWARD], device, torch.float32).reshape(-1),
            terminal=_t(arrays[tr.TERMINAL], device, torch.bool).reshape(-1),
            is_demo=_t(arrays.get(tr.IS_DEMO, np.zeros(b, bool)), device, torch.bool).reshape(-1),
            weights=_t(np.ones(b, np.float32) if weights is None else weights, device, torch.float32).reshape(-1),
            policy_version=opt(tr.POLICY_VERSION, torch.int64),
            voxel_indices=opt(tr.extra_name("voxel_indices"), torch.int64),
            attention_coordinates=opt(tr.extra_name("attention_coordinates"), torch.float32),
            rot_grip_indices=opt(tr.extra_name("rot_grip_indices"), torch.int64),
            n_rewards=opt(tr.N_REWARDS, torch.float32),
            bootstrap_steps=opt(tr.BOOTSTRAP_STEPS, torch.int64),
        )
