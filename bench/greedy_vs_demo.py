"""Where a trained run's greedy first pose goes, next to the scripted demo's first waypoint.

    python bench/greedy_vs_demo.py runs/<run-id> [--episodes 40]

Loads the run's newest learner checkpoint and config, resets the task on the evaluator's
seeds, and for each prints the greedy next-best pose, whether the control agent could reach
it, and the scripted first waypoint; then the x-y distance between the two and how many
greedy poses were unreachable. Useful when an evaluation curve stays flat: it tells a wrong
place from a wrong rotation from a pose the arm cannot reach.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from trained_run import load_trained_run  # noqa: E402  (bench/trained_run.py)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", type=Path, help="runs/<run-id> with config.yaml and checkpoints/learner")
    parser.add_argument("--episodes", type=int, default=40, help="evaluation seeds to look at")
    args = parser.parse_args()

    from actors.panda_env import PandaEnv
    from qattention.batch import ObservationBatch

    run = load_trained_run(args.run_dir)
    if run is None:
        return 1
    config, qconfig, agent = run.config, run.qconfig, run.agent
    env = PandaEnv(config.sim)
    print(f"{config.sim.task}, learner step {run.step}; pose = [x y z qx qy qz qw open]")
    distances, unreachable = [], 0
    for seed in range(config.actor.eval_seed, config.actor.eval_seed + args.episodes):
        obs = env.reset(seed=seed)
        demo = np.asarray(env.demo_waypoints()[0].action())
        act = agent.act(ObservationBatch.from_observations([obs], qconfig.cameras, "cpu"))
        greedy = np.asarray(act.action[0])
        step = env.step(greedy)
        unreachable += int(step.unreachable)
        distances.append(float(np.linalg.norm(greedy[:2] - demo[:2])))
        reached = f"unreachable ({step.info.get('reason')})" if step.unreachable else "reached"
        print(f"seed {seed}  greedy {np.round(greedy, 3)} {reached}\n{'':>14}demo {np.round(demo, 3)}")
    env.close()
    near = sum(d < 0.05 for d in distances)
    print(f"x-y distance greedy to demo: median {100 * statistics.median(distances):.1f} cm, "
          f"within 5 cm on {near}/{len(distances)}; unreachable {unreachable}/{len(distances)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
