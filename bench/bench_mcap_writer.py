"""Episode-file writers, before and after foxglove-sdk: bytes, write and read time per episode.

Records one scripted demo per configuration in the simulator, then writes it with the first layout
(``c2farm-demo/1``: JSON copies of Foxglove's schemas, base64 images, schemaless raw arrays, LZ4;
kept in ``protocol.episode_file_v1``) and with the current one (foxglove-sdk protobuf, zstd), and
reads each back with ``load_demo`` (everything, points re-derived) and ``read_episode_view`` (what
the dashboard reads). Times are the best of ``--repeats``, as CPU seconds of this process (the
writers are single-threaded here) and wall seconds; CPU seconds hold up on a busy machine.

    nice -n 19 .venv/bin/python bench/bench_mcap_writer.py --repeats 5
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from actors.demos.generate import record_demo
from actors.panda_env import PandaEnv
from actors.sim import SimConfig
from protocol.episode_file import load_demo, read_episode_view, write_demo
from protocol.episode_file_v1 import write_demo_v1

LAYOUTS = {"before (JSON + base64, c2farm-demo/1)": write_demo_v1, "after (foxglove-sdk, c2farm-demo/2)": write_demo}


def best(fn, repeats: int) -> tuple[float, float, object]:
    """(CPU s, wall s, result) of the fastest of ``repeats`` calls."""
    cpu = wall = float("inf")
    out = None
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        out = fn()
        cpu, wall = min(cpu, time.process_time() - c0), min(wall, time.perf_counter() - w0)
    return cpu, wall, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configs", default="pick_and_lift:front:128,lift_lid:front+wrist:128",
                    help="comma-separated task:cameras(+-joined):image size")
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    print("| task, cameras, size | frames | layout | MB/episode | write s CPU (wall) | load_demo s CPU "
          "| read_episode_view s CPU |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for spec in args.configs.split(","):
            task, cams, size = spec.split(":")
            env = PandaEnv(SimConfig(task=task, cameras=tuple(cams.split("+")), image_size=int(size)))
            demo = record_demo(env, args.seed)
            env.close()
            for i, (name, writer) in enumerate(LAYOUTS.items()):
                path = Path(tmp) / f"{task}-{i}.mcap"
                w_cpu, w_wall, size_b = best(lambda: writer(path, demo), args.repeats)
                l_cpu, _, _ = best(lambda: load_demo(path), args.repeats)
                v_cpu, _, _ = best(lambda: read_episode_view(path), args.repeats)
                print(f"| {task}, {cams}, {size} px | {len(demo.observations)} | {name} | {size_b / 1e6:.2f} "
                      f"| {w_cpu:.3f} ({w_wall:.3f}) | {l_cpu:.3f} | {v_cpu:.3f} |", flush=True)


if __name__ == "__main__":
    main()
