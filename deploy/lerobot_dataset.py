"""``c2farm export lerobot`` and ``c2farm import lerobot``: demos and episodes as LeRobot v3.0 datasets.

Export reads MCAP episode files (a demos folder, or the evaluation episodes a run records
under ``runs/<id>/eval/``) and writes one dataset (``protocol/lerobot_v3.py``, features in
``protocol/lerobot_demo.py``). A run's training episodes are not exported: the actors send
them to the replay server and record no files. Import turns a dataset carrying depth (or point
clouds) and camera matrices back into demo files the demo source sends. Bad input: one line,
exit code 2.
"""

from __future__ import annotations

import shutil
import sys
import time
from pathlib import Path

from protocol.episode_file import DemoFileError, load_demo, write_demo


class InterchangeError(ValueError):
    """Why a dataset cannot be written or read; one line."""


def episode_files(args) -> list[Path]:
    """The MCAP files ``--demos`` or ``--run`` names, in order."""
    if args.demos:
        folder = Path(args.demos)
        if not folder.is_dir():
            raise InterchangeError(f"{folder}: no such folder of demo files")
        files = sorted(folder.glob("*.mcap"))
        if not files:
            raise InterchangeError(f"{folder}: no demo files (*.mcap); write some with `c2farm demos`")
        return files
    run = Path(args.run)
    if not (run / "config.yaml").is_file():
        raise InterchangeError(f"{run}: not a run directory (no config.yaml; runs are under runs/<run-id>/)")
    if args.episodes == "train":
        raise InterchangeError(f"{run}: a run records no training episodes as files (the actors send them to the "
                               "replay server); export its evaluation episodes (--episodes eval) or its demos")
    files = sorted((run / "eval").glob("v*-seed*.mcap"))
    if not files:
        raise InterchangeError(f"{run}/eval: no evaluation episodes (the evaluator records them there while "
                               "actor.record_eval is on, once it has evaluated a weights version)")
    return files


def export_dataset(files: list[Path], out: Path, repo_id: str) -> tuple[int, int]:
    """Write ``files`` as a dataset at ``out``: (episodes, frames)."""
    from actors.demos.augmentation import SUCCESS_REWARD
    from actors.demos.keyframes import demo_keyframes
    from protocol import lerobot_demo
    from protocol.lerobot_v3 import DatasetWriter

    writer = None
    for path in files:
        demo = load_demo(path)
        if not demo.observations:
            raise InterchangeError(f"{path}: an episode without frames")
        first = demo.observations[0]
        cams, size = list(first.cameras), next(iter(first.cameras.values())).rgb.shape[0] if first.cameras else 0
        if writer is None:
            shape = (cams, size, demo.control_hz)
            writer = DatasetWriter(out, demo.control_hz, lerobot_demo.features(cams, size), lerobot_demo.ROBOT_TYPE,
                                   repo_id, episode_meta_types=lerobot_demo.META_TYPES)
        elif (cams, size, demo.control_hz) != shape:
            raise InterchangeError(f"{path}: cameras {cams} at {size} px, {demo.control_hz} Hz; the files before "
                                   f"it have {shape[0]} at {shape[1]} px, {shape[2]} Hz (one dataset, one layout)")
        # a policy episode's frames are its decisions: each is a keyframe; a demo's are found as training finds them
        keyframes = list(range(1, len(demo.observations))) if demo.actions else demo_keyframes(demo)
        writer.add(lerobot_demo.demo_episode(demo, keyframes, SUCCESS_REWARD))
    writer.finish()
    return len(writer.rows), writer.frames


def export_command(args) -> int:
    """``c2farm export lerobot``; one line and exit code 2 on bad input."""
    from protocol.lerobot_v3 import LeRobotFormatError

    out = Path(args.out)
    try:
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise InterchangeError(f"{out}: exists and is not an empty folder (the dataset needs its own)")
        files = episode_files(args)
    except InterchangeError as exc:
        print(f"c2farm: export lerobot: {exc}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    try:
        out.mkdir(parents=True, exist_ok=True)
        episodes, frames = export_dataset(files, out, args.repo_id or out.resolve().name)
    except (InterchangeError, DemoFileError, LeRobotFormatError, OSError) as exc:
        shutil.rmtree(out, ignore_errors=True)  # no half-written dataset left behind
        print(f"c2farm: export lerobot: {exc}", file=sys.stderr)
        return 2
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    print(f"c2farm export lerobot: {out} ({episodes} episodes, {frames} frames, {size / 1e6:.1f} MB, "
          f"{time.perf_counter() - start:.1f} s); check it with `lerobot-doctor {out}`")
    return 0


def import_dataset(root: Path, out: Path, task: str | None = None) -> list[Path]:
    """Write each episode of the dataset at ``root`` as a demo file under ``out``; the files written."""
    from protocol import lerobot_demo
    from protocol.lerobot_v3 import read_dataset

    dataset = read_dataset(root)
    if problem := lerobot_demo.import_problem(dataset.features):
        raise InterchangeError(f"{root}: cannot make demo files from it: it lacks {problem}")
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for i in range(len(dataset.episodes)):
        demo = lerobot_demo.episode_demo(dataset.episode(i), int(dataset.info["fps"]), task)
        path = out / f"{demo.task}_episode{dataset.episodes[i]['episode_index']:06d}.mcap"
        write_demo(path, demo)
        written.append(path)
    return written


def import_command(args) -> int:
    """``c2farm import lerobot``; one line and exit code 2 on bad input."""
    from protocol.lerobot_v3 import LeRobotFormatError

    if args.task is not None:
        from actors.sim.task_specs import TASKS

        if args.task not in TASKS:
            print(f"c2farm: import lerobot: unknown task {args.task!r}; known: {', '.join(TASKS)}", file=sys.stderr)
            return 2
    try:
        written = import_dataset(Path(args.dataset), Path(args.out), args.task)
    except (InterchangeError, LeRobotFormatError, ValueError, OSError) as exc:
        print(f"c2farm: import lerobot: {exc}", file=sys.stderr)
        return 2
    print(f"c2farm import lerobot: {len(written)} demo files in {args.out}; {run_hint(written[0])}")
    return 0


def run_hint(path: Path) -> str:
    """Where a run looks for these demos (its demo source sends demos.directory/<task>-<cameras>-<size>px/)."""
    from actors.sim.task_specs import TASKS
    from deploy.config import RunConfig
    from deploy.roles import demo_dir
    from protocol.episode_file import read_episode_view

    view = read_episode_view(path)
    if view.task not in TASKS:
        return f"{view.task!r} is no task of c2farm's; pass --task to name the one these demos are for"
    config = RunConfig()
    config.sim.task, config.sim.cameras = view.task, tuple(view.cameras)
    config.sim.image_size = view.rgb[view.cameras[0]][0].shape[0]
    return f"a run of {view.task} with these cameras sends them from {demo_dir(config)}/"
