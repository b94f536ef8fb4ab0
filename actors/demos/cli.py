"""``c2farm demos``: generate scripted demonstrations as MCAP files (mount with add_arguments + run)."""

from __future__ import annotations

import argparse
import sys

from actors.sim.task_specs import TASKS
from protocol.observation import CAMERA_NAMES


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task", required=True, help=f"task name, one of: {', '.join(TASKS)}")
    parser.add_argument("--episodes", type=_positive, default=10, help="number of successful demos to write (default 10)")
    parser.add_argument("--seed", type=_non_negative, default=0, help="seed of the first episode; later ones count up (default 0)")
    parser.add_argument("--out", required=True, help="output directory for the .mcap files")
    parser.add_argument("--cameras", default="front,left_shoulder,right_shoulder,wrist",
                        help=f"comma-separated cameras to record, from {','.join(CAMERA_NAMES)}")
    parser.add_argument("--image-size", type=_positive, default=128, help="square image size in pixels (default 128)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def _non_negative(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be 0 or more, got {value}")
    return value


def run(args: argparse.Namespace) -> int:
    from actors.demos.generate import generate_demos  # loads the simulator: not needed for --help
    from actors.sim.tasks import UnknownTaskError

    cameras = tuple(c for c in args.cameras.split(",") if c)
    try:
        s = generate_demos(args.task, args.episodes, args.seed, args.out, cameras=cameras,
                           image_size=args.image_size, progress=not args.no_progress)
    except (UnknownTaskError, ValueError, RuntimeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"{s.task}: wrote {len(s.written)} demos to {args.out} ({s.bytes / 1e6:.1f} MB, {s.seconds:.1f} s); "
          f"failed seeds retried: {len(s.failed_seeds)} {s.failed_seeds}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="c2farm demos", description=__doc__)
    add_arguments(parser)
    return run(parser.parse_args(argv))
