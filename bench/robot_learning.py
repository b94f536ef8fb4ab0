"""The robot's learning curve: C2F-ARM learning franky-sim's reach task as a robot actor, under a budget.

    python bench/robot_learning.py --minutes 60                        # one run (a rerun resumes it), then its curve
    python bench/robot_learning.py --minutes 60 --demos 0 --tag nodemos # no demonstrations
    python bench/robot_learning.py --minutes 60 --set actor.eval_episodes=5 --tag eval5
    python bench/robot_learning.py --plot-only                         # re-read the run, run nothing

The whole system runs as a user would run it on a robot, with franky-sim for the arm. First
``c2farm robot-demos`` records ``--demos`` demonstrations (the paper's 3 per real task) into the
run directory, before the budget starts, as a person would before training; then
``c2farm launch --robot franky-sim --camera mujoco`` runs the roles router, replay, dashboard,
learner, demo source and robot (no simulated actors or evaluator). A scripted operator
(``robot.scripted_operator``) moves the target before each episode and says "success" when the
grasp frame is within 2 cm of it, and demonstrates it: one top-down move onto the target.
With ``robot.evaluate`` the robot actor also plays the evaluator's greedy episodes (fixed
seeds, so fixed targets) every ``actor.eval_every_versions`` weights versions, into ``runs/<id>/metrics/eval.csv``, the
file bench/learning.py reads.

Ports are picked free (router, replay's ZeroMQ, dashboard), so this runs beside another run.
Budget bookkeeping, reading and plotting are bench/learning.py's (``runs/<id>/bench_budget.json``).

Outputs: ``runs/<id>/learning_curve.{csv,png}`` and ``<results-dir>/robot-reach-<preset>[-<tag>]-s<seed>.csv``,
one row per greedy evaluation: minutes, env steps, learner step, weights version, success rate,
episodes, unreachable rate (poses the safety limits refused or the arm could not take); then every
seed's CSV there combined as bench/learning.py does (``success_rate`` = the worst seed's) into
``robot-reach-<preset>[-<tag>].{csv,png}``. Run seeds one after another (``--seed 2``, ``--seed 3``).
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
from pathlib import Path
from typing import Optional, Sequence

import learning  # bench/learning.py: budget, launcher supervision, curves, plots
import learning_curves  # bench/learning_curves.py
import run_budget  # bench/run_budget.py

ROBOT_ROLES = "router,replay,dashboard,learner,robot"
#: franky-sim with the MuJoCo stand-in camera and the scripted operator, for the demos and the run alike.
#: The arm moves at 0.3 of the Panda's limits (robot.franka's 0.1 is the cautious start on a real arm):
#: franky-sim runs slower than real time here, and this measures learning, not caution.
ROBOT_FLAGS = ["--task", "reach_target", "--robot", "franky-sim", "--camera", "mujoco",
               "--set", "robot.scripted_operator=true", "--set", "robot.franka.dynamics_factor=0.3"]


def demos_dir(args: argparse.Namespace) -> Path:
    """``demos.directory`` of the run: its demos live in the run directory."""
    return Path(args.runs_dir) / args.run_id / "demos-robot"


def user_sets(args: argparse.Namespace) -> list[str]:
    return [word for item in args.set for word in ("--set", item)]


def demos_command(args: argparse.Namespace, episodes: int) -> list[str]:
    """``c2farm robot-demos``: the scripted operator demonstrates ``episodes`` more reaches."""
    return [sys.executable, "-m", "deploy.cli", "robot-demos", "--preset", args.preset, *ROBOT_FLAGS,
            "--episodes", str(episodes), "--set", f"demos.directory={demos_dir(args)}", *user_sets(args)]


def record_demos(args: argparse.Namespace) -> bool:
    """Record the demos the run still lacks (a rerun keeps the ones it has); False if recording failed."""
    have = len(list(demos_dir(args).glob("*/*.mcap")))
    if have >= args.demos:
        return True
    cmd = demos_command(args, args.demos - have)
    print(f"{args.run_id}: recording {args.demos - have} demos\n+ {' '.join(cmd)}", flush=True)
    return subprocess.run(cmd).returncode == 0


def launch_command(args: argparse.Namespace) -> list[str]:
    """``c2farm launch`` of the robot run on free ports; the user's ``--set`` items come last, so they win."""
    from deploy.endpoints import free_port

    roles = ROBOT_ROLES + (",demo_source" if args.demos else "")
    return [
        sys.executable,
        "-m",
        "deploy.cli",
        "launch",
        "--preset",
        args.preset,
        *ROBOT_FLAGS,
        "--run-id",
        args.run_id,
        "--roles",
        roles,
        "--router-port",
        "0",
        "--dashboard-port",
        str(args.dashboard_port),
        "--set",
        f"replay.zmq_endpoint=tcp://127.0.0.1:{free_port()}",
        "--set",
        f"run.runs_dir={args.runs_dir}",
        "--set",
        f"run.seed={args.seed}",
        "--set",
        "robot.evaluate=true",
        "--set",
        f"demos.directory={demos_dir(args)}",
        "--set",
        f"demos.episodes={args.demos}",
        *user_sets(args),
    ]


def results_stem(args: argparse.Namespace) -> str:
    return f"robot-reach-{args.preset}" + (f"-{args.tag}" if args.tag else "")


def parse_args(argv: Optional[Sequence[str]]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=60.0, help="wall-clock budget of the run, over all reruns")
    parser.add_argument(
        "--preset", default="robot", help="config preset in configs/ (robot: 3 demos, training from 16 transitions)"
    )
    parser.add_argument("--seed", type=int, default=1, help="run.seed")
    parser.add_argument(
        "--demos", type=int, default=3, help="scripted demos recorded before the run (the paper: 3); 0 = none"
    )
    parser.add_argument("--tag", default=None, help="names a variant in the run id and result files")
    parser.add_argument("--run-id", default=None, help="run id (default: learn-robot-reach-<preset>[-<tag>]-s<seed>)")
    parser.add_argument("--runs-dir", default="runs", help="where runs live")
    parser.add_argument("--results-dir", default="bench/results", help="where the curve goes")
    parser.add_argument("--dashboard-port", type=int, default=0, help="dashboard port (0: a free one, printed)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    parser.add_argument("--thresholds", type=float, nargs="+", default=[0.5, 0.8], help="success rates to time")
    parser.add_argument("--plot-only", action="store_true", help="only re-read and re-plot the run")
    args = parser.parse_args(argv)
    args.run_id = args.run_id or f"learn-{results_stem(args)}-s{args.seed}"
    return args


def train(args: argparse.Namespace) -> bool:
    """The run's (remaining) budget; False if the launcher failed by itself."""
    run_dir = Path(args.runs_dir) / args.run_id
    left = run_budget.load_budget(run_dir).remaining(args.minutes * 60)
    if left <= 0:
        print(f"{args.run_id}: budget of {args.minutes:g} min already spent", flush=True)
        return True
    if not record_demos(args):
        print(f"{args.run_id}: recording the demos failed", flush=True)
        return False
    cmd = launch_command(args)
    print(f"{args.run_id}: {left / 60:.1f} of {args.minutes:g} min left\n+ {' '.join(cmd)}", flush=True)
    code = run_budget.run_budgeted(cmd, run_dir, args.minutes * 60)
    if code is not None:
        print(f"{args.run_id}: launcher exited by itself with code {code}", flush=True)
    return not code


def write_results(args: argparse.Namespace) -> learning_curves.Curve:
    """This seed's curve, then every seed's under the results dir combined (worst seed), as CSVs and a PNG.

    Seeds are combined from their per-seed CSVs (``<stem>-s<seed>.csv``), not from run
    directories, so seeds run in different sessions or on different machines still combine.
    """
    run_dir = Path(args.runs_dir) / args.run_id
    learning_curves.plot(run_dir)
    curve = learning_curves.read_eval(run_dir)
    results, stem = Path(args.results_dir), results_stem(args)
    if curve:
        learning_curves.write_csv(results / f"{stem}-s{args.seed}.csv", curve, learning_curves.curve_fields(curve))
    seeds = {int(p.stem[len(stem) + 2:]): learning_curves.read_curve_csv(p)
             for p in sorted(results.glob(f"{stem}-s*.csv"))
             if p.stem[len(stem) + 2:].isdigit()}  # not another tag's: robot-reach-robot-slow-s1
    if seeds:
        combined = learning_curves.aggregate(list(seeds.values()))
        learning_curves.write_csv(results / f"{stem}.csv", combined, learning_curves.AGGREGATE_FIELDS)
        named = {f"seed {seed}": c for seed, c in sorted(seeds.items())}
        learning_curves.plot_seeds(named, combined, results / f"{stem}.png",
                                   f"{stem}: greedy success, {len(seeds)} seed(s)")
        print(f"wrote {results / stem}.csv and {stem}.png from {len(seeds)} per-seed CSV(s)")
        print(learning_curves.summarise(named, combined, args.thresholds))
    return curve


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = parse_args(argv)
    ok = True
    if not args.plot_only:
        previous = signal.signal(signal.SIGTERM, learning._interrupt)
        try:
            ok = train(args)
        except KeyboardInterrupt:
            print("interrupted; rerun the same command to resume", flush=True)
        finally:
            signal.signal(signal.SIGTERM, previous)
    curve = write_results(args)
    return 0 if ok and curve else 1


if __name__ == "__main__":
    sys.exit(main())
