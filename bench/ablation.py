"""Sample-efficiency levers side by side: every variant on the same seeds and budget, in one table.

    python bench/ablation.py --task push_button --minutes 10 --seeds 3                  # every lever
    python bench/ablation.py --task push_button --minutes 10 --seeds 3 --variants default base no-margin
    python bench/ablation.py --task push_button --minutes 10 --seeds 3 --stop-at 0.9    # a run ends once it holds 90 %
    python bench/ablation.py --task push_button --seeds 3 --summary                     # read, run nothing
    python bench/ablation.py --list                                                     # the levers

A variant is the preset (``default``) with one lever turned (``LEVERS``); ``base`` turns every
sample-efficiency lever off, which is the reference's algorithm. Seeds run interleaved (seed 1 of
every variant, then seed 2, ...), so a host that drifts slower or busier hits every variant
alike. Each run is ``bench/learning.py --tag <variant>``'s: resumable (rerun the command), with
its curves under ``bench/results/<task>-<preset>-<variant>[-s<seed>].{csv,png}``.

The table (markdown, for BENCHMARKS.md; also written to ``bench/results/ablation-<task>-<preset>.md``)
gives, per variant and seed, when greedy success first reached each threshold (minutes, env
steps, learner step), then the variant's slowest seed: the headline, since a lever helps only if
the worst seed gets there sooner. ``samples/insert`` is the replay's sampled / inserted
transitions over the whole run (the first ``min_size_to_sample`` inserts included, so a held
target reads a little under itself); ``--stop-at`` ends each run once it holds a rate, so
``end`` is then the rate it held and when, not the budget's end. A seed whose run directory is
gone (another machine) is read back from its CSV in the results dir.

Under the table, a second one holds every other lever measured on the task and preset, from its
per-seed CSVs, so an ablation of one lever never drops the earlier levers' rows; those ran under
their own budgets and stop rules (``end`` says where each seed stopped).
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path
from typing import Mapping, Optional, Sequence

import learning  # bench/learning.py: runs and their seeds
from learning_curves import Curve, first_reaching, read_curve_csv, when_reached

#: Coarse-to-fine depth and voxel size, the paper's study written as (voxels per axis at each depth): a depth-d
#: cube is centred on the voxel chosen before it, half-width bounds_offset[d-1]. Each grid spells out all three
#: fields, so none inherits the preset's or an entry's (the cpu-small preset's is (8,8,8) since 2026-12-07).
GRIDS: dict[str, tuple[str, ...]] = {
    "16-16": ("qattention.voxel_size=16", "qattention.depths=2", "qattention.bounds_offset=0.15"),  # the paper's
    "8-8": ("qattention.voxel_size=8", "qattention.depths=2", "qattention.bounds_offset=0.15"),  # 3.75 cm last voxels
    "8-8-8": ("qattention.voxel_size=8", "qattention.depths=3", "qattention.bounds_offset=[0.15, 0.075]"),  # 1.9 cm
    "16-16-16": ("qattention.voxel_size=16", "qattention.depths=3", "qattention.bounds_offset=[0.15, 0.0375]"),
    # The last cube 10 cm wide, not 15: 1.25 cm voxels at the last depth, not 1.9 (stack_wine's greedy poses at
    # revision 2 were 0.7-2.0 cm from the demos', the last voxel one off at the carry in 4 of 5 demos).
    "8-8-8-fine": ("qattention.voxel_size=8", "qattention.depths=3", "qattention.bounds_offset=[0.15, 0.05]"),
}
GRID_8_8_8 = GRIDS["8-8-8"]


def grid_name(qconfig) -> str:
    """A cascade's grid as the paper writes it: voxels per axis at each depth, (8,8,8)."""
    return "(" + ",".join([str(qconfig.voxel_size)] * qconfig.depths) + ")"


HEADS_WHOLE = ("qattention.last_translation_td=1.0", "qattention.last_head_margin=1.0")

#: Variant name -> config overrides on top of the preset. Each turns one lever of issue 13.
LEVERS: dict[str, tuple[str, ...]] = {
    "default": (),
    "base": ("replay.demo_fraction=0.0", "replay.n_step=1", "actor.reachable_top_k=0", "qattention.demo_margin=0.0"),
    "no-demo-share": ("replay.demo_fraction=0.0",),
    "one-step": ("replay.n_step=1",),
    "no-top-k": ("actor.reachable_top_k=0",),
    "no-margin": ("qattention.demo_margin=0.0",),
    "unreachable-minus-1": ("sim.unreachable_reward=-1.0",),
    "uniform-exploration": ("qattention.exploration=uniform",),
    "epsilon-0.2": ("actor.epsilon=0.2",),
    "epsilon-decay": ("actor.epsilon_decay_updates=300",),  # 0.1 -> 0.02 over the first 300 updates
    "acting-average": ("learner.acting_average=0.99",),
    # The replay's rate limiter holds samples per insert within 100 transitions of the target, both
    # ways: the learner waits for inserts, and inserts (so the actors, through their outboxes) wait
    # for samples. Unheld, a 2-core host settled near 1.1 (push_button) and 1.45 (pick_and_lift).
    "spi-1": ("replay.samples_per_insert=1.0", "replay.samples_per_insert_error_buffer=100",
              "replay.limit_inserts=true", "replay.insert_wait_timeout_s=30"),
    "spi-2": ("replay.samples_per_insert=2.0", "replay.samples_per_insert_error_buffer=100",
              "replay.limit_inserts=true", "replay.insert_wait_timeout_s=30"),
    "spi-4": ("replay.samples_per_insert=4.0", "replay.samples_per_insert_error_buffer=100",
              "replay.limit_inserts=true", "replay.insert_wait_timeout_s=30"),
    "bf16": ("qattention.bf16=true",),  # where auto resolves to fp32 (no native bf16)
    "fp32": ("qattention.bf16=false",),  # where auto resolves to bf16 (AVX-512-bf16, AMX, GPU)
    "yaw-augmentation": ("qattention.demo_yaw_augmentation=45",),
    # The grids on the preset (GRIDS): (16,16) is the paper's, and was cpu-small's until 2026-12-07.
    **{f"grid-{grid}": levers for grid, levers in GRIDS.items()},
    # Cameras fused into one grid (the paper adds wrist and shoulder views where the front one is occluded).
    "front-wrist": ("sim.cameras=[front, wrist]",),
    "four-cameras": ("sim.cameras=[front, left_shoulder, right_shoulder, wrist]",),
    "front-wrist-grid-8-8-8": ("sim.cameras=[front, wrist]", *GRID_8_8_8),  # lift_lid's first ladder entry
    # The proprioception's time value held at +1: augmented demos restart the decision count at 0
    # mid-episode, so the count pairs badly with the scene (put_in_bin's imitation-only study).
    "untimed": ("qattention.time_feature=false",),
    "demos-0.5": ("replay.demo_fraction=0.5",),  # 4 of 8 sampled transitions from the demos
    "untimed-demos-0.5": ("qattention.time_feature=false", "replay.demo_fraction=0.5"),
    # The last depth's translation Q stays near 0 while its target is ~0.5: its TD is one of five
    # heads averaged, against the whole L1 regulariser over every voxel. A fifth of the regulariser:
    "untimed-demos-0.5-qreg-0.2": ("qattention.time_feature=false", "replay.demo_fraction=0.5",
                                   "qattention.lambda_trans_qreg=0.2"),
    # ... or its TD weighed as a whole head (the other depths' weight):
    "untimed-demos-0.5-last-td-1": ("qattention.time_feature=false", "replay.demo_fraction=0.5",
                                    "qattention.last_translation_td=1.0"),
    # lift_lid's ladder entry: the first one with both (its seed 2 swung below 80 % for 30 minutes).
    "lid-entry-untimed-demos-0.5": ("sim.cameras=[front, wrist]", *GRID_8_8_8,
                                    "qattention.time_feature=false", "replay.demo_fraction=0.5"),
    # Each of the last depth's five heads weighed as a whole, in the TD (translation) and in the demo margin:
    # put_in_bin's greedy gripper chose "closed" at every demo keyframe, open trailing by a near-constant 0.05.
    "untimed-demos-0.5-heads-1": ("qattention.time_feature=false", "replay.demo_fraction=0.5",
                                  *HEADS_WHOLE),
    "lid-entry-heads-1": ("sim.cameras=[front, wrist]", *GRID_8_8_8, "qattention.time_feature=false",
                          "replay.demo_fraction=0.5", *HEADS_WHOLE),
    # ... and a decision that changes nothing costing 10 % of the value instead of 1 %: at gamma 0.99 keeping the
    # gripper closed above the bin (the same state again) is worth 0.99 of letting go, a gap below the Q noise.
    # ... or the actors and evaluator acting with a slow average of the weights (put_in_bin's greedy rate swung
    # between 0 and 55 % from one evaluation to the next under heads-1):
    "lid-heads-1-acting-0.99": ("sim.cameras=[front, wrist]", *GRID_8_8_8, "qattention.time_feature=false",
                                "replay.demo_fraction=0.5", *HEADS_WHOLE, "learner.acting_average=0.99"),
    # The drawer tasks' entry: the front camera looks at the chest's back, so its handles face away from it (at
    # open_drawer's approach keyframe the last depth's cube held 0-3 occupied voxels from front + wrist). The two
    # shoulder cameras see the chest's front (20-87 there); the front view adds nothing at the keyframes.
    "shoulders-heads-1-acting-0.99": ("sim.cameras=[left_shoulder, right_shoulder, wrist]", *GRID_8_8_8,
                                      "qattention.time_feature=false", "replay.demo_fraction=0.5", *HEADS_WHOLE,
                                      "learner.acting_average=0.99"),
    # ... with the time value in the proprioception: put_item_in_drawer has four open-gripper keyframes in a row
    # (the handle's approach, the pull, the lift off the handle, the block's approach), so without it the states
    # after the pull and after the lift read alike but for the arm in the images; at learner step 2,492 of its
    # first ladder seed the greedy pose from the second was the lift again in 2 of 3 demos (40 cm off the block).
    "drawer-entry-timed": ("sim.cameras=[left_shoulder, right_shoulder, wrist]", *GRID_8_8_8,
                           "replay.demo_fraction=0.5", *HEADS_WHOLE, "learner.acting_average=0.99"),
    "lid-heads-1-gamma-0.9": ("sim.cameras=[front, wrist]", *GRID_8_8_8, "qattention.time_feature=false",
                              "replay.demo_fraction=0.5", *HEADS_WHOLE, "qattention.gamma=0.9"),
}

#: The paper's depth and voxel-size study on the take-lid and rubbish-in-bin tasks, run on the entries those
#: rungs learn with (lift_lid's, put_in_bin's) with only the grid changed: ``lid-grid-16-16`` ...
#: ``release-grid-8-8-8-fine`` (bench/grid_study.py).
ENTRY_LEVERS = {  # each entry without its grid
    "lid": ("sim.cameras=[front, wrist]", "qattention.time_feature=false", "replay.demo_fraction=0.5"),
    "release": ("sim.cameras=[front, wrist]", "qattention.time_feature=false", "replay.demo_fraction=0.5",
                *HEADS_WHOLE, "learner.acting_average=0.99"),
}
LEVERS.update({f"{entry}-grid-{grid}": (*levers, *GRIDS[grid])
               for entry, levers in ENTRY_LEVERS.items() for grid in GRIDS})
#: stack_wine's greedy episodes at 3,950 updates (bench/greedy_trace.py): 11 of 20 never grasped, each repeating one
#: pose with the gripper open (the grasp's, or the approach's) until the episode ran out. At gamma 0.99 a decision
#: that changes nothing costs 1 % of the value against acting now, below the Q noise; at 0.9 it costs 10 %.
#: (Seed 1, 60 min: 60 % at best, as the entry; the loops stayed, with the gripper shut: BENCHMARKS.md.)
LEVERS["release-gamma-0.9"] = (*ENTRY_LEVERS["release"], *GRID_8_8_8, "qattention.gamma=0.9")
#: ... or the time value kept in the proprioception (as the reference keeps it, and as put_item_in_drawer's entry
#: does): a repeated decision then changes the state, and the steps left are in it, so a loop is no longer a fixed
#: point of the greedy policy. (Seed 1: 45 % at best, 10-25 % over its last 1,600 updates; stopped at 36 min.)
LEVERS["release-timed"] = tuple(lever for lever in (*ENTRY_LEVERS["release"], *GRID_8_8_8)
                                if lever != "qattention.time_feature=false")
#: ... or the acting rule that ends the loops where they start: a choice that repeats the gripper's pose (its voxel,
#: rotation bins and gripper state) gives way to the best one that moves (qattention/repeats.py). (Seed 1, 60 min:
#: 50 % first at 1,150 updates, 65 % at best, 40-65 % over its last 20 evaluations; the loops gone: BENCHMARKS.md.
#: At task revision 3, one layout: 70 % on seeds 1-3 at 10.4, 19.7 and 17.0 min, 940-2,080 updates; the ladder's entry.)
LEVERS["release-skip-repeats"] = (*ENTRY_LEVERS["release"], *GRID_8_8_8, "actor.skip_repeats=true")
#: ... and with gamma 0.9: at 0.9 the greedy grasp came right in 18-19 of 20 scenes, but the policy then held on at
#: the grasp or the lift, repeating its pose, which the rule breaks. (Seed 1: 35 % at best, a mean of 15 % over its
#: second and third thousand updates against the rule's 29-34 %, 25 % of evaluation episodes unreachable; stopped
#: at 26 min.)
LEVERS["release-gamma-0.9-skip-repeats"] = (*LEVERS["release-gamma-0.9"], "actor.skip_repeats=true")
#: ... with the gripper and rotation read also from the final features at the translation Q's best voxel (a change to
#: the paper's head, q_attention.best_voxel_features): at 4,915 updates of the rule's seed 2, 6 of 20 greedy
#: episodes never grasped, reaching the grasp pose 0.7-2.6 cm from the demo's with "open" ahead by +0.11 to +0.26,
#: where the 8 successes chose "shut" there by -0.08 to -0.23; the head saw only the whole cube's features.
LEVERS["release-skip-repeats-best-voxel"] = (*LEVERS["release-skip-repeats"], "qattention.head_reads_best_voxel=true")
#: put_item_in_drawer's entry with the finer last voxel (1.25 cm, the last cube 10 cm wide, at the same update cost):
#: on lift_lid it took the worst of 3 seeds to 80 % in 200 updates against (8,8,8)'s 350 (bench/grid_study.py);
#: the drawer's worst seed needed more updates than its hour gave (35 % at best in 4,820). (Seed 3: 50 % first at
#: 50.2 min, 4,250 updates, 70 % at best; seed 1: 40 % at best in 60 min, 5,260 updates, where the entry's seed 1
#: reached 50 % at 4,400: not the lever that meets the bar on every seed.)
LEVERS["drawer-timed-fine"] = (*(lever for lever in LEVERS["drawer-entry-timed"] if lever not in GRID_8_8_8),
                               *GRIDS["8-8-8-fine"])
#: ... evaluated every 100 updates instead of every 50: on 2 cores the evaluator (20 seeded episodes per version, each
#: rendered by three cameras, planned and recorded) is never idle, and took as much of the CPU as the learner and the
#: actor (61, 65 and 66 % of the 200 % by `ps`, stack_wine at 22 min); the drawer's seeds needed 4,250-4,980
#: updates for the bar and the learner ran 1.34-1.56 updates/s. Training is unchanged; the curve is coarser. (Seed 3,
#: stopped at 44.7 min: 4,360 updates and 8,411 env steps against the entry's 3,600 and 6,921 at that minute; 20 % at
#: best, its first success no sooner in updates.)
LEVERS["drawer-timed-eval-100"] = (*LEVERS["drawer-entry-timed"], "actor.eval_every_versions=10")
#: The replay's byte cap, not its 20,000 transitions, bounds what the cpu-small preset keeps: its 2 GiB held 6,430
#: stack_wine transitions (front + wrist, ~330 KB each) from ~2,400 updates on, and 4,100 of put_item_in_drawer's
#: (three cameras, ~520 KB) from ~1,600, evicting the oldest agent episodes after that. stack_wine's late sag (seeds
#: 1-2 of revision 3) begins about there, which may be chance. 8 GiB (the replay's own default) keeps a 60-minute
#: run whole; it costs that much memory and ~2.5 times as much disk for the replay's checkpoints (5.0 GB at 2 GiB).
#: Not run yet.
REPLAY_8G = "replay.capacity_bytes=8589934592"
LEVERS["drawer-timed-replay-8g"] = (*LEVERS["drawer-entry-timed"], REPLAY_8G)
LEVERS["release-skip-repeats-replay-8g"] = (*LEVERS["release-skip-repeats"], REPLAY_8G)
#: put_item_in_drawer's entry with each demo's keyframe jumps stored once (demos.chain_keyframes=1): the authors'
#: augmentation runs every chain to the demo's end, so the task's nine keyframes in ~160 frames gave its first one,
#: the handle's approach, 5 % of the demo transitions (open_drawer's: 25 %), and the first decision was the one its
#: seed 2 got wrong (23 % of late evaluation episodes ended there, the pose at the handle). Cut, 16-21 %. (Seed 2,
#: AVX2-only host: 30 % at best in 98.5 min / 4,400 updates; first poses fixed, 68 % of its episodes then stopped at
#: the handle's grasp, 4 cm into the drawer front: BENCHMARKS.md.)
LEVERS["drawer-timed-jumps-once"] = (*LEVERS["drawer-entry-timed"], "demos.chain_keyframes=1")


def learning_args(args: argparse.Namespace, variant: str, seed: int) -> list[str]:
    """bench/learning.py's arguments for one seed of one variant (the tag names the variant)."""
    argv = ["--task", args.task, "--minutes", f"{args.minutes:g}", "--preset", args.preset, "--seeds", "1",
            "--first-seed", str(seed), "--tag", variant, "--runs-dir", args.runs_dir,
            "--results-dir", args.results_dir]
    for item in (*LEVERS[variant], *args.set):
        argv += ["--set", item]
    if args.stop_at is not None:
        argv += ["--stop-at", f"{args.stop_at:g}", "--stop-held", str(args.stop_held)]
    return argv


def variant_args(args: argparse.Namespace, variant: str) -> argparse.Namespace:
    """bench/learning.py's view of the variant: every seed of it, not only the one a run was for."""
    parsed = learning.parse_args(learning_args(args, variant, args.first_seed))
    parsed.seeds = args.seeds
    return parsed


def seed_curves(args: argparse.Namespace, variant: str) -> dict[int, Curve]:
    """The variant's seeds in range: each run's eval.csv, else the seed's CSV in the results dir.

    Each curve read from a run also gets, on its last point, the samples per insert the replay had reached
    by the learner's last logged batch (``samples_per_insert``), the ratio the replay-ratio levers turn.
    """
    parsed = variant_args(args, variant)
    curves = learning.load_seeds(parsed)
    run_ids = learning.seed_run_ids(parsed)
    for seed, curve in curves.items():
        ratio = achieved_samples_per_insert(Path(args.runs_dir) / run_ids[seed])
        if ratio is not None:
            curve[-1]["samples_per_insert"] = ratio
    return curves


def recorded_curves(results_dir: str, task: str, preset: str, variants: Sequence[str]) -> dict[str, dict[int, Curve]]:
    """The named levers' per-seed curves written to the results dir (``<task>-<preset>-<variant>-s<seed>.csv``)."""
    prefix = f"{task}-{preset}-"
    found: dict[str, dict[int, Curve]] = {}
    for path in sorted(Path(results_dir).glob(f"{prefix}*-s*.csv")):
        variant, _, seed = path.stem[len(prefix):].rpartition("-s")
        if variant in variants and seed.isdigit():
            found.setdefault(variant, {})[int(seed)] = read_curve_csv(path)
    return found


def achieved_samples_per_insert(run_dir: Path) -> Optional[float]:
    """The replay's sampled/inserted transitions at the learner's last logged batch (learner.csv)."""
    try:
        with (run_dir / "metrics" / "learner.csv").open(newline="") as f:
            rows = list(csv.DictReader(f))
        return float(rows[-1]["replay_samples_per_insert"])
    except (FileNotFoundError, IndexError, KeyError, TypeError, ValueError):
        return None


def slowest(curves: Sequence[Curve], threshold: float) -> Optional[dict]:
    """The latest first-reaching point over the seeds; None if any seed never got there."""
    points = [first_reaching(curve, threshold) for curve in curves]
    if not points or any(p is None for p in points):
        return None
    return max(points, key=lambda p: (p["minutes"], p["env_steps"]))


def table(results: Mapping[str, Mapping[int, Curve]], thresholds: Sequence[float]) -> str:
    """Markdown: per variant, each seed's time to each threshold, then the slowest seed's."""
    header = (["variant", "seed"] + [f"first ≥ {100 * t:g} %" for t in thresholds]
              + ["end", "evals", "samples/insert"])
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for variant, by_seed in results.items():
        for seed, curve in sorted(by_seed.items()):
            cells = [variant, str(seed)] + [when_reached(first_reaching(curve, t)) for t in thresholds]
            ratio = curve[-1].get("samples_per_insert")
            cells += [
                f"{100 * curve[-1]['success_rate']:.0f} % at {curve[-1]['minutes']:.1f} min",
                str(len(curve)),
                "" if ratio is None else f"{ratio:.2f}",
            ]
            lines.append("| " + " | ".join(cells) + " |")
        if len(by_seed) > 1:
            cells = [f"**{variant}**", "slowest"] + [when_reached(slowest(list(by_seed.values()), t))
                                                      for t in thresholds]
            worst_final = min(c[-1]["success_rate"] for c in by_seed.values())
            lines.append("| " + " | ".join(cells + [f"{100 * worst_final:.0f} %", "", ""]) + " |")
    return "\n".join(lines)


def parse_args(argv: Optional[Sequence[str]]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="push_button", help="task to learn")
    parser.add_argument("--minutes", type=float, default=10.0, help="wall-clock budget per run")
    learning.add_seed_arguments(parser, 3, "per variant")
    parser.add_argument(
        "--variants", nargs="+", default=list(LEVERS), metavar="NAME", help="levers to compare (--list)"
    )
    parser.add_argument("--thresholds", type=float, nargs="+", default=[0.5, 0.9], help="success rates to time")
    learning.add_stop_arguments(parser)
    learning.add_place_arguments(parser)
    parser.add_argument("--summary", action="store_true",
                        help="run nothing: read the runs (or their seed CSVs), write the table and aggregates")
    parser.add_argument("--list", action="store_true", help="print the levers and what each overrides")
    args = parser.parse_args(argv)
    unknown = [v for v in args.variants if v not in LEVERS]
    if unknown:
        parser.error(f"unknown variant(s) {', '.join(unknown)}; known: {', '.join(LEVERS)}")
    if args.seeds < 1 or args.minutes <= 0:
        parser.error("--seeds must be >= 1 and --minutes > 0")
    learning.check_stop_arguments(parser, args)
    for variant in args.variants:  # the variant's name is its runs' tag
        if error := learning.run_id_error(argparse.Namespace(**{**vars(args), "tag": variant, "prefix": None})):
            parser.error(error)
    return args


def main(argv: Optional[Sequence[str]] = None) -> int:
    args = parse_args(argv)
    if args.list:
        for name, overrides in LEVERS.items():
            print(f"{name:>20}  {' '.join(overrides) or '(the preset as it is)'}")
        return 0
    failed = [] if args.summary else learning.run_each(
        (f"{variant} seed {seed}", learning_args(args, variant, seed))
        for seed in range(args.first_seed, args.first_seed + args.seeds) for variant in args.variants)
    if failed is None:
        return 130
    # Every seed of each variant: those in range, and those recorded before (seeds run a few at a time)
    recorded = recorded_curves(args.results_dir, args.task, args.preset, args.variants)
    results = {variant: {**recorded.get(variant, {}), **seed_curves(args, variant)} for variant in args.variants}
    for variant, by_seed in results.items():  # each run wrote its own seed's aggregate: now every seed's
        if by_seed:
            parsed = variant_args(args, variant)
            learning.write_results(parsed, by_seed, learning.combine(parsed, by_seed))
    text = table({v: c for v, c in results.items() if c}, args.thresholds)
    others = recorded_curves(args.results_dir, args.task, args.preset,
                             [v for v in LEVERS if v not in args.variants])
    out = Path(args.results_dir) / f"ablation-{args.task}-{args.preset}.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    early = (f", stopped once {args.stop_held} evaluations in a row reached {100 * args.stop_at:g} %"
             if args.stop_at is not None else "")
    body = f"{args.task}, preset {args.preset}, {args.minutes:g} min per run{early}\n\n{text}\n"
    if others:
        body += (f"\nThe other levers measured on {args.task} with this preset, from their per-seed CSVs "
                 f"(each with the budget and stop rule it ran under):\n\n{table(others, args.thresholds)}\n")
    out.write_text(body)
    print(text)
    print(f"wrote {out}")
    return learning.exit_code(failed)


if __name__ == "__main__":
    sys.exit(main())
