"""``c2farm robot-demos``: demonstrations recorded on the arm, from the operator's waypoints (a file or typed).

It writes demo files into the run's demo folder and joins no run; the demo source then sends
them like simulated ones.
"""

from __future__ import annotations

import sys
from pathlib import Path


def run(args, config) -> int:
    """``c2farm robot-demos``: the operator's waypoints, recorded on the arm into the run's demo folder."""
    from actors.robot.demos import read_waypoints, record_demos
    from deploy.roles import demo_dir

    try:
        if config.robot.scripted_operator:  # franky-sim: the scripted operator demonstrates its reach task
            waypoints = []
        elif args.waypoints:
            waypoints = read_waypoints(Path(args.waypoints).read_text().splitlines())
        else:
            print("waypoints, one per line: x y z [qx qy qz qw] open|close [via]; an empty line ends", flush=True)
            waypoints = typed_waypoints()
    except (OSError, ValueError) as exc:  # a missing file or a bad line: one line, before the arm moves
        print(f"c2farm: {exc}", file=sys.stderr)
        return 2
    if not waypoints and not config.robot.scripted_operator:
        print("c2farm: no waypoints", file=sys.stderr)
        return 2
    written = record_demos(config, waypoints, args.episodes or config.demos.episodes, demo_dir(config))
    print(f"{len(written)} robot demos in {demo_dir(config)}")
    return 0


def typed_waypoints() -> list:
    """Waypoints typed in the terminal until an empty line; a mistyped line is said and typed again."""
    from actors.robot.demos import parse_waypoint, read_waypoints

    lines: list[str] = []
    for line in iter(lambda: sys.stdin.readline().rstrip("\n"), ""):
        try:
            parse_waypoint(line)
        except ValueError as exc:
            print(f"{exc}; type it again", flush=True)
            continue
        lines.append(line)
    return read_waypoints(lines)
