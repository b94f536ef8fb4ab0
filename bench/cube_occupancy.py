"""What each depth of the cascade sees around the demos' keyframe poses: occupied voxels per cube, per grid.

    python bench/cube_occupancy.py --task put_in_bin --set "sim.cameras=[front, wrist]"
    python bench/cube_occupancy.py --task stack_wine --demos 10 --grids grid-16-16 grid-8-8-8 grid-16-16-16

A depth's Q-map can only rank voxels by what its cube holds. Records ``--demos`` scripted demos
(seeds from 0), and at each keyframe state (the demo from its first frame) voxelises the cube
each depth would see on the way to the demo's own next pose: depth 0 the whole scene, each finer
depth the cube centred on the voxel the depth before it labels. Prints, per grid (the levers of
``bench/ablation.py`` that set one) and keyframe, the fewest and most occupied voxels over the
demos at every depth. A 0 means a depth that sees empty space there: its Q-map cannot tell the
demo's voxel from any other, and a greedy pose from it is noise. A pose high above the place it
leads to (a release above a bin) is where that happens. Needs no trained run.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from ablation import LEVERS  # noqa: E402  (bench/ablation.py)
from demo_fit import batch_of, by_keyframe, demo_transitions  # noqa: E402  (bench/demo_fit.py)

#: Grid levers only: each overrides nothing but the cascade's voxel size, depths and cube sizes.
GRIDS = ("grid-16-16", "grid-8-8", "grid-8-8-8", "grid-16-16-16")


def occupied_per_depth(rows, qconfig) -> list[list[int]]:
    """Per row, occupied voxels in each depth's cube on the way to the row's (demo's) next pose."""
    import torch

    from qattention.action_codec import encode_action
    from qattention.cascade import depth_grid

    batch = batch_of(rows, qconfig.cameras, qconfig.scene_bounds)
    with torch.no_grad():
        labels = encode_action(batch.action, batch.obs.bounds(qconfig.scene_bounds), qconfig)
        counts = []
        for d in range(qconfig.depths):
            centre = labels.coordinates[:, d - 1] if d else None
            grid = depth_grid(batch.obs, qconfig, centre, labels.bounds[:, d])
            counts.append(grid[:, -1].flatten(1).sum(1).long())  # the last channel is occupancy
    return torch.stack(counts, 1).tolist()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="put_in_bin")
    parser.add_argument("--preset", default="cpu-small")
    parser.add_argument("--demos", type=int, default=5, help="scripted demos to read (seeds from 0)")
    parser.add_argument("--grids", nargs="+", default=list(GRIDS), choices=GRIDS, help="grid levers to compare")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="config override for every grid (e.g. the entry's cameras)")
    args = parser.parse_args()

    from actors.panda_env import PandaEnv
    from deploy.config import load_config
    from deploy.config_loader import parse_override
    from deploy.roles import network_config

    def config_of(grid: str):
        overrides = map(parse_override, (*LEVERS[grid], *args.set))
        return load_config(preset=args.preset, overrides=({"sim": {"task": args.task}}, *overrides))

    first = config_of(args.grids[0])
    env = PandaEnv(first.sim)  # the grids share the scene and cameras, so the demos are recorded once
    try:
        rows, used = demo_transitions(env, args.demos, every_n=10**9)  # the first frame's episode only
    finally:
        env.close()
    print(f"{args.task}, cameras {', '.join(first.sim.cameras)}, demos {used}: occupied voxels per depth's cube "
          "(fewest-most over the demos), depth 0 first\n")
    header = None
    for grid in args.grids:
        qconfig = network_config(config_of(grid))
        keyframes = by_keyframe(rows, occupied_per_depth(rows, qconfig))
        if header is None:
            header = "| grid | " + " | ".join(f"keyframe {k + 1}" for k in sorted(keyframes)) + " |"
            print(header)
            print("|---" * (len(keyframes) + 1) + "|")
        cells = [" / ".join(f"{min(c[d] for c in cs)}-{max(c[d] for c in cs)}" for d in range(qconfig.depths))
                 for _, cs in sorted(keyframes.items())]
        print(f"| {grid} ({qconfig.voxel_size}³ x {qconfig.depths}) | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
