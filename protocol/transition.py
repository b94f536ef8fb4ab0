"""A sampled transition, named once: what the replay's gather writes, the wire carries, the learner's guard
checks and ``qattention.TransitionBatch`` reads.

One row of a batch is transition ``t`` of an episode (``protocol.episode``) and carries:

- every observation array of step ``t`` under its episode name (``front_rgb``, ``gripper_pose``,
  the act-time labels ``extra_voxel_indices`` ... and any other ``extra_*``, see :func:`extra_name`), and the
  observation the transition leads to under the same name + ``NEXT`` (``front_rgb_tp1``);
- the step fields of :data:`STEP_FIELDS` (``action``, ``reward``, ...), and with n-step returns
  the two of :data:`NSTEP_FIELDS`;
- the sampling fields of :data:`SAMPLING_FIELDS` the sample service adds (which item, its
  importance weight), which the learner hands back with new priorities.

``reward`` is always step t's own reward; ``n_rewards`` holds the rewards of steps t .. t + m - 1
of an n-step transition (m = ``bootstrap_steps``), zeros past the episode's end.
"""

from __future__ import annotations

import numpy as np

from protocol.observation import Observation

#: Suffix of the arrays of the observation a transition leads to (t + 1, or t + m for n-step).
NEXT = "_tp1"
#: Prefix of an observation's extra arrays on the wire and in batches (act-time labels among them).
EXTRA_PREFIX = "extra_"

ACTION, REWARD, TERMINAL, TIMEOUT = "action", "reward", "terminal", "timeout"
POLICY_VERSION, IS_DEMO = "policy_version", "is_demo"
N_REWARDS, BOOTSTRAP_STEPS = "n_rewards", "bootstrap_steps"
INDICES, KEYS, WEIGHTS, PROBABILITIES = "indices", "keys", "weights", "probabilities"

#: Every row's step fields: name -> (dtype, trailing shape, meaning).
STEP_FIELDS: dict[str, tuple[str, tuple[int, ...], str]] = {
    ACTION: ("float32", (8,), "the next-best pose taken at t: xyz, quaternion xyzw, gripper open"),
    REWARD: ("float32", (), "the reward of step t"),
    TERMINAL: ("bool", (), "the episode ended with the transition's last step (timeouts included)"),
    TIMEOUT: ("bool", (), "it ended there because it ran out of decisions"),
    POLICY_VERSION: ("int64", (), "weights version that chose the action (-1: a demo)"),
    IS_DEMO: ("bool", (), "demonstration data"),
}
#: The n-step fields (replay ``n_step`` > 1 only): name -> (dtype, trailing shape, meaning); "n" is n.
NSTEP_FIELDS: dict[str, tuple[str, tuple, str]] = {
    N_REWARDS: ("float32", ("n",), "rewards of steps t .. t + m - 1, zeros past the episode's end"),
    BOOTSTRAP_STEPS: ("int64", (), "m: decisions from the observation to the next one, 1..n"),
}
#: What the sample service adds to a batch: name -> (dtype, meaning).
SAMPLING_FIELDS: dict[str, tuple[str, str]] = {
    INDICES: ("int64", "the replay slot of each row (handed back with its new priority)"),
    KEYS: ("int64", "the item's key at sampling time (a priority for an overwritten item is dropped)"),
    WEIGHTS: ("float32", "importance-sampling weight, normalised by the largest in the batch"),
    PROBABILITIES: ("float32", "the probability the row was drawn with, within its table (demo or agent)"),
}

#: The observation extra holding the depth-0 box it was taken for (a robot's is not the simulator's).
SCENE_BOUNDS = "scene_bounds"

#: Act-time labels the actor records with each observation (as ``extra_`` + name), read by the
#: learner: name -> (trailing shape, "D" being the cascade depth, allowed dtypes).
ACT_LABELS: dict[str, tuple[tuple, tuple[str, ...]]] = {
    "voxel_indices": (("D", 3), ("int32", "int64")),
    "attention_coordinates": (("D", 3), ("float32", "float64")),
    "rot_grip_indices": ((4,), ("int32", "int64")),
}


def next_name(name: str) -> str:
    """The batch name of an observation array of the next observation: ``front_rgb`` -> ``front_rgb_tp1``."""
    return name + NEXT


def extra_name(name: str) -> str:
    """The wire and batch name of observation extra ``name``: ``voxel_indices`` -> ``extra_voxel_indices``."""
    return EXTRA_PREFIX + name


def act_label_blanks(depths: int) -> dict[str, np.ndarray]:
    """Zero labels for an observation nobody acted on (an episode's last, demo frames), by label name.

    Every observation of a replay then carries the same arrays; the learner relabels demo rows
    and never reads a last observation's labels.
    """
    return {"voxel_indices": np.zeros((depths, 3), np.int64),
            "attention_coordinates": np.zeros((depths, 3), np.float32),
            "rot_grip_indices": np.zeros(4, np.int64)}


def pad_act_labels(observations: list[Observation], depths: int) -> None:
    """Give observations without act-time labels zero ones (:func:`act_label_blanks`), in place."""
    blank = act_label_blanks(depths)
    for obs in observations:
        for name, value in blank.items():
            obs.extras.setdefault(name, value)


def stamp_scene_bounds(observations: list[Observation], bounds) -> None:
    """Let every observation carry the depth-0 box it was taken for (``extra_scene_bounds``), unless
    it already does: the learner then voxelises each sample in its own box (a robot's is not the
    simulator's)."""
    box = np.asarray(bounds, dtype=np.float32).reshape(6)
    for obs in observations:
        obs.extras.setdefault(SCENE_BOUNDS, box)
