"""Moving on: a next-best pose that repeats the pose the gripper holds gives way to the best one that moves.

A keyframe action is a pose, so choosing the voxel the gripper is in, the rotation bins it holds
and the gripper state it has commands nothing: the scene stays as it was. Without the time value
in the proprioception the next observation is then the one just seen, and a greedy policy makes
the same choice again until the episode runs out (stack_wine's greedy episodes: 11 of 20 at the
approach or grasp pose with the gripper open, bench/greedy_trace.py). Under the discount the
repeat is worth gamma times acting now, a 1 % gap at 0.99 that the estimates' noise covers.

With ``skip_repeats`` the cascade takes the best choice that moves instead: the same pose with
the gripper toggled, or one of the last depth's best other voxels and rotations (the candidates
of reachability.py), ranked by the sum of the translation, mean rotation and gripper values
(every head regresses the same TD target, so their values share one scale). The TD target still
takes its max over every choice, the repeat included; only acting changes, as with the top-K
reachability rule.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from .reachability import ReachabilityTest, candidate_pose, inside_workspace, ranked_candidates
from .voxelise import voxel_centre

#: Candidates looked at when the reachability rule is off (its ``top_k`` is their number otherwise).
CANDIDATES = 8


class Held(NamedTuple):
    """The pose the gripper holds now, as a choice of the last depth would be compared with it."""

    position: torch.Tensor  #: [3] the gripper's xyz
    rotation: torch.Tensor  #: [3] the Euler bins of its orientation
    gripper_open: float  #: 1 open, 0 closed


def repeats_pose(centre: torch.Tensor, rotation: torch.Tensor, grip: int, bounds: torch.Tensor, voxel_size: int,
                 held: Held) -> bool:
    """Whether the last depth's choice (voxel ``centre`` [3] of the cube ``bounds`` [6], Euler bins
    ``rotation`` [3], gripper index ``grip``) is the pose ``held``: its position lies in the chosen
    voxel, its rotation is the same bins, the gripper stays as it is."""
    half_edge = (bounds[3:] - bounds[:3]) / (2 * voxel_size)
    inside = bool(((centre - held.position).abs() <= half_edge).all())
    return inside and bool((rotation == held.rotation).all()) and grip == int(round(held.gripper_open))


def moving_choice(voxel: torch.Tensor, rotation: torch.Tensor, grip: int, q_trans: torch.Tensor,
                  q_rot: torch.Tensor, q_grip: torch.Tensor, bounds: torch.Tensor, workspace: torch.Tensor,
                  held: Held, config, separation: int, reachable: ReachabilityTest | None = None,
                  k: int = CANDIDATES):
    """(tests run, (voxel [3], bins [3], grip) or None): the best choice that does not repeat the pose.

    ``voxel``, ``rotation``, ``grip`` are the choice that repeats ``held``; ``q_trans`` [V, V, V], ``q_rot``
    [3, bins] and ``q_grip`` [2] the last depth's values for one sample. Candidates are the
    same pose with the gripper toggled, and the ``k`` best voxel and rotation pairs inside the
    ``workspace`` with the gripper as chosen; each is tested for reachability (when a test is
    given) best first. None when no candidate both moves and is reachable: the repeat stands.
    """
    v = config.voxel_size

    def value(vox: torch.Tensor, bins: torch.Tensor, g: int) -> float:
        return float(q_trans[vox[0], vox[1], vox[2]] + q_rot[torch.arange(3), bins].float().mean() + q_grip[g])

    scored = [(value(voxel, rotation, 1 - grip), voxel, rotation, 1 - grip)]
    inside = inside_workspace(bounds, v, workspace)
    for other_voxel, bins in zip(*ranked_candidates(q_trans, q_rot, k, separation, inside=inside)):
        centre = voxel_centre(other_voxel, bounds, v)
        if not repeats_pose(centre, bins, grip, bounds, v, held):
            scored.append((value(other_voxel, bins, grip), other_voxel, bins, grip))
    checks = 0
    for _, cand_voxel, bins, g in sorted(scored, key=lambda s: -s[0]):
        if reachable is not None:
            checks += 1
            pose = torch.cat([candidate_pose(cand_voxel, bins, bounds, config).cpu(), torch.tensor([float(g)])])
            if not reachable(pose.numpy()):
                continue
        return checks, (cand_voxel, bins, g)
    return checks, None

