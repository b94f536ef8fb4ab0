"""What a trained run chooses at the demos' keyframes: the first thing to read when its greedy gripper never changes.

    python bench/keyframe_choices.py runs/<run-id>              # 5 demos of the run's task
    python bench/keyframe_choices.py runs/<run-id> --demos 10

Loads the run's newest learner checkpoint and config, records ``--demos`` scripted demos of its
task (seeds from 0, as the run's demos), and at every keyframe state (the demo from its first
frame, no augmentation) asks the networks two things:

- the gripper head's two Q-values in the last depth's cube around the demo's own next pose
  (what the update trains): ``open - closed`` and whether the demo's choice leads;
- the greedy next-best pose from that state: its distance to the demo's next pose, the first depth
  whose voxel differs from the demo's (0: the coarse grid over the whole scene already points
  elsewhere), whether its rotation bins are the demo's and how far its rotation is from the demo's
  (the bins' own rounding, up to half a bin per axis, included), and its gripper;
- each depth's Q at the demo's own voxel (in the cube the demo's path leads to).

Printed per keyframe index, over the demos. A gripper head that leads with the same choice by
about the same amount at every keyframe has not learnt the gripper from the scene: a policy
that never lets go (put_in_bin, stack_wine) or never opens to grasp. Where the greedy pose is
far from the demo's, the translation is what to look at instead.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from demo_fit import batch_of, by_keyframe, demo_transitions  # noqa: E402  (bench/demo_fit.py)
from trained_run import load_trained_run  # noqa: E402  (bench/trained_run.py)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two orientations given as quaternions (either sign), in degrees."""
    dot = abs(float(np.dot(a / np.linalg.norm(a), b / np.linalg.norm(b))))
    return float(np.degrees(2 * np.arccos(min(dot, 1.0))))


def keyframe_rows(agent, config, rows) -> list[dict]:
    """Per demo keyframe state: each depth's Q at the demo's voxel, the gripper's Q gap, and the greedy choice.

    The labels are the demo's next pose encoded without crop noise, so each depth's cube is the one
    centred on the demo's own voxel: where the greedy cascade first picks another voxel says which
    depth sends the pose away (depth 0's 8- or 16-voxel grid over the whole scene, or a finer one).
    A depth whose Q there reads near 0 where the others read near 1 has a flat map: its best voxel
    is noise (bench/cube_occupancy.py says whether it sees anything at all).
    """
    import torch

    from qattention.action_codec import encode_action
    from qattention.cascade import depth_grid, split_rot_grip

    batch = batch_of(rows, config.cameras, config.scene_bounds)
    every = torch.arange(batch.size)
    agent.nets.eval()
    with torch.no_grad():
        labels = encode_action(batch.action, batch.obs.bounds(config.scene_bounds), config)
        demo_q = []
        for d in range(config.depths):
            centre = labels.coordinates[:, d - 1] if d else None
            q, q_rg = agent.nets[d](depth_grid(batch.obs, config, centre, labels.bounds[:, d]),
                                    batch.obs.proprioception(config))
            i = labels.voxel_indices[:, d]
            demo_q.append(q.float()[every, i[:, 0], i[:, 1], i[:, 2]])
        _, grip = split_rot_grip(q_rg.float(), config.rotation_bins)  # the last depth's, as the update trains it
        greedy = agent.act(batch.obs)
    demo_q = torch.stack(demo_q, 1).tolist()
    demo_voxels, demo_rot_grip = labels.voxel_indices.numpy(), labels.rot_grip.numpy()
    out = []
    for i, row in enumerate(rows):
        label = int(demo_rot_grip[i, 3])
        gap = float(grip[i, 1] - grip[i, 0])  # index 1 = open
        off = [d for d in range(config.depths) if (greedy.voxel_indices[i, d] != demo_voxels[i, d]).any()]
        out.append({"label_open": label == 1, "gap": gap, "label_leads": (gap > 0) == (label == 1),
                    "distance": float(np.linalg.norm(greedy.action[i, :3] - row[1][:3])),
                    "greedy_open": bool(greedy.action[i, 7] > 0.5),
                    "first_depth_off": off[0] if off else None,
                    "rotation_same": bool((greedy.rot_grip_indices[i, :3] == demo_rot_grip[i, :3]).all()),
                    "rotation_deg": angle_deg(np.asarray(greedy.action[i, 3:7]), np.asarray(row[1][3:7])),
                    "demo_q": demo_q[i]})
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", type=Path, help="runs/<run-id> with config.yaml and checkpoints/learner")
    parser.add_argument("--demos", type=int, default=5, help="scripted demos to read (seeds from 0)")
    args = parser.parse_args()

    from actors.panda_env import PandaEnv

    run = load_trained_run(args.run_dir)
    if run is None:
        return 1
    config, qconfig, agent = run.config, run.qconfig, run.agent
    env = PandaEnv(config.sim)
    try:
        rows, used = demo_transitions(env, args.demos, every_n=10**9)  # the first frame's episode only
    finally:
        env.close()
    by_index = by_keyframe(rows, keyframe_rows(agent, qconfig, rows))

    print(f"{config.sim.task}, learner step {run.step}, demos {used}\n")
    depths = ", ".join(f"{d}" for d in range(qconfig.depths))
    print("| keyframe | demo's gripper | demo's gripper leads | Q(open) - Q(closed), median (min, max) "
          f"| greedy: distance to the demo's pose (median) | greedy: first depth off the demo's voxel ({depths}, none) "
          "| greedy: rotation bins the demo's | greedy: rotation off the demo's, median (max) "
          f"| greedy: gripper open | Q at the demo's voxel per depth ({depths}), "
          "median |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for k, rs in sorted(by_index.items()):
        gaps, n = [r["gap"] for r in rs], len(rs)
        label = "open" if rs[0]["label_open"] else "closed"
        leads, opens = sum(r["label_leads"] for r in rs), sum(r["greedy_open"] for r in rs)
        distance = 100 * statistics.median(r["distance"] for r in rs)
        spread = f"{statistics.median(gaps):+.3f} ({min(gaps):+.3f}, {max(gaps):+.3f})"
        first_off = [sum(r["first_depth_off"] == d for r in rs) for d in (*range(qconfig.depths), None)]
        rotation = sum(r["rotation_same"] for r in rs)
        degrees = [r["rotation_deg"] for r in rs]
        demo_q = " / ".join(f"{statistics.median(r['demo_q'][d] for r in rs):.2f}" for d in range(qconfig.depths))
        print(f"| {k + 1} | {label} | {leads}/{n} | {spread} | {distance:.1f} cm | {' / '.join(map(str, first_off))} "
              f"| {rotation}/{n} | {statistics.median(degrees):.1f}° ({max(degrees):.1f}°) | {opens}/{n} | {demo_q} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
