"""Timings of the Q-attention cascade: acting latency, update() per batch size, voxelisation.

    python bench/bench_qattention.py                 # CPU table (~10 min on 2 cores)
    python bench/bench_qattention.py --device cuda   # GPU: paper preset up to batch 128
    python bench/bench_qattention.py --quick         # smaller batches only
    python bench/bench_qattention.py --grids grid-16-16 grid-8-8 grid-8-8-8 grid-16-16-16   # update cost per grid

Inputs come from qattention.synthetic (ray-cast table + sphere, 128x128 cameras). Each
number is the median of 3 timed calls after one warm-up call; on CPU, batches above the
smallest are timed once (warmed up by the smaller batch) and only for the two presets as
chosen, the other variants (padding, precision) only at the smallest batch. Variants whose batch-1 acting latency is
above --slow-act-s are not updated at larger batches (bf16 without AVX-512 is emulated).
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import torch  # noqa: E402

from qattention import C2FARM, ObservationBatch, TransitionBatch, cpu_small, paper  # noqa: E402
from qattention.crop import gather_points  # noqa: E402
from qattention.synthetic import observation_arrays, transition_arrays  # noqa: E402
from qattention.voxelise import voxelise  # noqa: E402


def sync(device):
    if device.type == "cuda":
        torch.cuda.synchronize()


def timed(fn, device, repeats=3, warmup=1, give_up_s=1.5):
    """Median of ``repeats`` calls after ``warmup``; a warm-up slower than ``give_up_s`` is the answer."""
    for _ in range(warmup):
        t = time.perf_counter()
        fn()
        sync(device)
        if time.perf_counter() - t > give_up_s and repeats <= 5:
            return time.perf_counter() - t
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        sync(device)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def variants(device_type):
    """(name, config, time batch 128 on CPU?): only the two presets as chosen get the slow batch."""
    sm, pp = cpu_small().replace(bf16=False), paper().replace(bf16=False)  # fp32 rows; bf16 rows say so
    if device_type == "cuda":
        return [
            ("paper", pp, True),
            ("paper", pp.replace(padding="zeros"), True),
            ("paper", pp.replace(bf16=True), True),
            ("paper", pp.replace(padding="zeros", bf16=True), True),
        ]
    return [
        ("cpu-small", sm, True),
        ("cpu-small", sm.replace(padding="replicate"), False),
        ("cpu-small", sm.replace(bf16=True), False),
        ("paper", pp, True),
        ("paper", pp.replace(padding="zeros"), False),
        ("paper", pp.replace(bf16=True, padding="zeros"), False),
    ]


def grid_cost(overrides, device, batch: int) -> dict:
    """The cpu-small cascade on one grid (``qattention.*`` overrides only): params, act B=1 and update seconds."""
    from deploy.config_loader import parse_override

    changes: dict = {}
    for item in overrides:
        (section, rest), = parse_override(item).items()
        if section != "qattention":
            raise ValueError(f"{item!r} is not a grid setting: it sets {section}")
        changes.update(rest)
    if isinstance(changes.get("bounds_offset"), list):
        changes["bounds_offset"] = tuple(changes["bounds_offset"])
    cfg = cpu_small().replace(**changes)
    from ablation import grid_name  # bench/ablation.py (bench/ is on the path where this runs)

    agent = C2FARM(cfg, device, seed=0)
    data = TransitionBatch.from_arrays(transition_arrays(batch, seed=batch), ("front",), device)
    obs1 = ObservationBatch.from_arrays(observation_arrays(1, seed=1), ("front",), device)
    return {
        "grid": grid_name(cfg),
        "offsets": ", ".join(f"{cfg.offset(d):g}" for d in range(1, cfg.depths)),
        "params": sum(p.numel() for p in agent.nets.parameters()),
        "act_s": timed(lambda: agent.act(obs1), device, repeats=5),
        "update_s": timed(lambda: agent.update(data), device, repeats=5, give_up_s=float("inf")),
    }


def time_grids(names, device, batch: int) -> None:
    """Acting latency and update time of the cpu-small cascade for each grid lever of bench/ablation.py."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from ablation import LEVERS

    print(f"| grid (voxels per depth) | bounds offsets | params | act B=1 (ms) | update B={batch} (s) | updates/s |")
    print("|---|---|---|---|---|---|")
    for name in names:
        try:
            cost = grid_cost(LEVERS[name], device, batch)
        except ValueError as e:
            raise SystemExit(f"{name} is not a grid lever: {e}")
        print(f"| {cost['grid']} ({name}) | {cost['offsets']} | {cost['params']:,} | {cost['act_s'] * 1000:.0f} "
              f"| {cost['update_s']:.2f} | {1 / cost['update_s']:.2f} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--quick", action="store_true", help="batches 8 and 32 only")
    ap.add_argument("--batches", type=int, nargs="*", default=None)
    ap.add_argument("--slow-act-s", type=float, default=1.5)
    ap.add_argument("--grids", nargs="+", default=None, metavar="LEVER",
                    help="only time these grid levers of bench/ablation.py (grid-16-16 ...), cpu-small, batch 8")
    ap.add_argument("--threads", type=int, default=None,
                    help="torch threads (default: 1 on CPU, robust when other processes share the cores)")
    args = ap.parse_args()
    device = torch.device(args.device)
    if args.threads or device.type == "cpu":
        torch.set_num_threads(args.threads or 1)
    torch.manual_seed(0)
    import warnings

    warnings.simplefilter("ignore")
    gpu = torch.cuda.get_device_name(0) if device.type == "cuda" else None
    print(f"# torch {torch.__version__}, {gpu or platform.processor() or 'cpu'}, threads {torch.get_num_threads()}, "
          f"cpu capability {torch.backends.cpu.get_cpu_capability()}\n")

    if args.grids:
        time_grids(args.grids, device, (args.batches or [8])[0])
        return
    batches = args.batches or ([8, 32] if args.quick else [8, 32, 128])
    big_ok = device.type == "cuda"
    data = {b: TransitionBatch.from_arrays(transition_arrays(b, seed=b), ("front",), device) for b in batches}
    obs1 = ObservationBatch.from_arrays(observation_arrays(1, seed=1), ("front",), device)

    print("| preset | padding | precision | params (d0 + d1) | act B=1 (ms) | " +
          " | ".join(f"update B={b} (s)" for b in batches) + " |")
    print("|---|---|---|---|---|" + "---|" * len(batches))
    for name, cfg, full in variants(device.type):
        agent = C2FARM(cfg, device, seed=0)
        params = sum(p.numel() for p in agent.nets.parameters())
        act = timed(lambda: agent.act(obs1), device, repeats=5)
        cells = []
        for b in batches:
            if act > args.slow_act_s or (b > min(batches) and not (full or big_ok)):
                cells.append("-")
                continue
            one = b > min(batches) and not big_ok  # CPU: one call, warmed up by the smaller batch
            t = timed(lambda: agent.update(data[b]), device, repeats=1 if one else 3, warmup=0 if one else 1,
                      give_up_s=float("inf"))
            cells.append(f"{t:.2f}" + (" (1 run)" if one else ""))
        prec = "bf16" if cfg.bf16 else "fp32"
        print(f"| {name} | {cfg.padding} | {prec} | {params:,} | {act * 1000:.0f} | " + " | ".join(cells) + " |",
              flush=True)


    print("\n| voxelisation 16^3 | 1 camera | 4 cameras |\n|---|---|---|")
    cams = ("front", "left_shoulder", "right_shoulder", "wrist")
    for b in (1, 32):
        row = []
        for n in (1, 4):
            obs = ObservationBatch.from_arrays(observation_arrays(b, cams[:n], seed=b), cams[:n], device)
            bounds = obs.bounds(paper().scene_bounds)
            row.append(timed(lambda: voxelise(*gather_points(obs, cams[:n]), bounds, 16), device, repeats=5) * 1000)
        print(f"| B={b} ({128 * 128:,} points per camera) | {row[0]:.1f} ms | {row[1]:.1f} ms |")


if __name__ == "__main__":
    main()
