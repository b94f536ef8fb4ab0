"""What the live view (``--foxglove``) costs the evaluator: decisions/s with and without it.

    python bench/bench_live_view.py [--task pick_and_lift] [--rounds 6] [--decisions 15] [--preset cpu-small]

An evaluator-like loop on the preset's simulator and network: per decision the real
``agent.act`` on the real observation (a random-init cascade), then ``env.step`` to the task's
scripted keyframe instead of the network's pose, so every episode runs all its keyframes (a
random cascade's own pose is mostly unreachable and would end each episode after one
decision: that would time resets, not decisions). Resets are inside the timing, as in the
evaluator. Wall clock and this process's CPU time (the live view's server threads included;
the client's process not) are both reported: on shared cores the CPU time is the steadier
measure of the cost; the wall-clock slowdown compares the median rounds, so one round starved by
other work does not make the verdict. Three variants, interleaved round by round on the same seeds:

- ``no live view``: the loop alone;
- ``live view, no client``: ``LiveView.wrap(env)`` and ``on_decision=live.show_decision``, as
  ``c2farm eval --foxglove`` runs, nobody connected;
- ``live view, 1 client``: the same with a Foxglove WebSocket client (subprotocol
  ``foxglove.sdk.v1``) subscribed to every channel and reading every message, in its own process
  as Foxglove would be (a thread here would take the loop's GIL).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import re
import statistics
import struct
import subprocess
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
VARIANTS = ("no live view", "live view, no client", "live view, 1 client")


def read_everything(url: str, conn) -> None:
    """A Foxglove client: subscribe to every channel advertised, receive every message; answer ``conn``'s
    "count" with (messages, bytes, channels advertised, channels heard from) so far, and stop on "stop".

    A subscription refused as "Unknown channel ID" (foxglove-sdk can advertise a channel a moment
    before it takes subscriptions) is sent again, as tests/test_live_view.py's client does.
    """
    from websockets.sync.client import connect

    def subscribe(ids: list[int]) -> None:
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": i} for i in ids]}))

    messages = received = 0
    advertised: set[int] = set()
    heard: set[int] = set()
    with connect(url, subprotocols=["foxglove.sdk.v1"], max_size=None) as ws:
        while True:
            if conn.poll():
                request = conn.recv()
                conn.send((messages, received, len(advertised), len(heard)))
                if request == "stop":
                    return
            try:
                raw = ws.recv(timeout=0.05)
            except TimeoutError:
                continue
            if isinstance(raw, str):
                msg = json.loads(raw)
                if msg["op"] == "advertise":
                    new = [c["id"] for c in msg["channels"] if c["id"] not in advertised]
                    advertised.update(new)
                    subscribe(new)
                elif msg["op"] == "status" and (refused := re.match(r"Unknown channel ID: (\d+)", msg["message"])):
                    subscribe([int(refused.group(1))])
            elif raw[0] == 1:  # message data: the subscription id is the channel id
                messages, received = messages + 1, received + len(raw)
                heard.add(struct.unpack_from("<I", raw, 1)[0])


def play(env, agent, cameras, decisions: int, first_seed: int, on_decision=None) -> tuple[float, float, int, int]:
    """(wall seconds, this process's CPU seconds, episodes, episodes cut short) for ``decisions`` decisions, resets
    included: act on each observation, step to the keyframe. Cut short: a keyframe was unreachable."""
    from qattention.batch import ObservationBatch

    done, seed, short = 0, first_seed, 0
    start, cpu = time.perf_counter(), time.process_time()
    while done < decisions:
        obs = env.reset(seed=seed)
        seed += 1
        for keyframe in env.demo_waypoints():
            act = agent.act(ObservationBatch.from_observations([obs], cameras, agent.device))
            if on_decision is not None:
                on_decision(obs, act)
            result = env.step(keyframe.action(), linear=keyframe.linear)
            obs, done = result.observation, done + 1
            short += int(result.unreachable)
            if result.terminal or result.unreachable or done >= decisions:
                break
    return time.perf_counter() - start, time.process_time() - cpu, seed - first_seed, short


def ask(conn, request: str = "count") -> tuple[int, ...]:
    conn.send(request)
    return conn.recv()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="pick_and_lift")
    parser.add_argument("--preset", default="cpu-small")
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--decisions", type=int, default=15, help="per variant per round")
    args = parser.parse_args()

    import torch

    from actors.live_view import LiveView
    from actors.panda_env import PandaEnv
    from deploy.config import load_config
    from deploy.roles import network_config
    from qattention.agent import C2FARM

    torch.set_num_threads(1)  # an evaluator's one core (actor.torch_threads)
    torch.manual_seed(0)
    config = load_config(preset=args.preset, overrides=({"sim": {"task": args.task}},))
    qconfig = network_config(config).replace(epsilon=0.0)
    env = PandaEnv(config.sim)
    agent = C2FARM(qconfig, device=torch.device("cpu"))
    quiet, watched = LiveView(port=0), LiveView(port=0)
    here, there = mp.get_context("spawn").Pipe()
    client = mp.get_context("spawn").Process(target=read_everything, args=(f"ws://127.0.0.1:{watched.port}", there),
                                             daemon=True)
    client.start()
    runs = {VARIANTS[0]: (env, None), VARIANTS[1]: (quiet.wrap(env), quiet.show_decision),
            VARIANTS[2]: (watched.wrap(env), watched.show_decision)}
    try:
        for loop, on_decision in runs.values():  # warm-up: every channel advertised, the client subscribed
            play(loop, agent, qconfig.cameras, 4, 10_000, on_decision)
        deadline = time.monotonic() + 600
        while (counts := ask(here))[2] != counts[3] and time.monotonic() < deadline:  # until it hears every channel
            play(runs[VARIANTS[2]][0], agent, qconfig.cameras, 1, 10_000, runs[VARIANTS[2]][1])
        before = ask(here)
        seconds: dict[str, list[float]] = {v: [] for v in VARIANTS}
        cpu, episodes, short = dict.fromkeys(VARIANTS, 0.0), dict.fromkeys(VARIANTS, 0), dict.fromkeys(VARIANTS, 0)
        for r in range(args.rounds):
            for v in VARIANTS if r % 2 == 0 else VARIANTS[::-1]:  # alternate the order: drifts in load cancel
                loop, on_decision = runs[v]
                t, c, n, cut = play(loop, agent, qconfig.cameras, args.decisions, 1000 * r, on_decision)
                seconds[v].append(t)
                cpu[v], episodes[v], short[v] = cpu[v] + c, episodes[v] + n, short[v] + cut
        after = ask(here, "stop")
        messages, received = after[0] - before[0], after[1] - before[1]
    finally:
        client.join(timeout=10)
        if client.is_alive():
            client.kill()
        quiet.close()
        watched.close()
        env.close()

    n = args.decisions * args.rounds
    median = {v: args.decisions / statistics.median(seconds[v]) for v in VARIANTS}  # a round's decisions/s
    base_cpu = cpu[VARIANTS[0]] / n
    print(f"live view cost to an evaluator-like loop: {args.task}, preset {args.preset} "
          f"({', '.join(qconfig.cameras)} {config.sim.image_size} px, voxel grid {qconfig.voxel_size}^3 x "
          f"{qconfig.depths} depths), {args.rounds} rounds x {args.decisions} decisions per variant, 1 torch thread")
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    wall, used = sum(map(sum, seconds.values())), sum(cpu.values())
    shared = "; other work shared the cores: read the CPU columns" if used < 0.9 * wall else ""
    print(f"CPU: {cpu_model()}; commit {commit()}; load average at the end {load}; the loop had "
          f"{100 * used / wall:.0f} % of a core ({used:.0f} CPU s in {wall:.0f} s{shared})")
    print()
    print("| variant | decisions | episodes (cut short) | seconds | decisions/s | median round decisions/s "
          "| slowdown vs no live view (median rounds) | CPU ms per decision | CPU vs no live view |")
    print("|---|---|---|---|---|---|---|---|---|")
    for v in VARIANTS:
        s = sum(seconds[v])
        slowdown = "-" if v == VARIANTS[0] else f"{100 * (median[VARIANTS[0]] / median[v] - 1):+.1f} %"
        more_cpu = "-" if v == VARIANTS[0] else f"{100 * (cpu[v] / n / base_cpu - 1):+.1f} %"
        print(f"| {v} | {n} | {episodes[v]} ({short[v]}) | {s:.1f} | {n / s:.2f} | {median[v]:.2f} | {slowdown} "
              f"| {1e3 * cpu[v] / n:.0f} | {more_cpu} |")
    print()
    print("decisions/s per round (wall clock): " + "; ".join(
        f"{v}: {', '.join(f'{args.decisions / t:.2f}' for t in seconds[v])}" for v in VARIANTS))
    print()
    print(f"the client received {messages} messages ({received / 1e6:.1f} MB) in its variant's "
          f"{sum(seconds[VARIANTS[2]]):.0f} s, from {after[3]} of the {after[2]} channels advertised")


def cpu_model() -> str:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
    except OSError:
        return "unknown"
    return next((line.split(":", 1)[1].strip() for line in out.splitlines() if line.startswith("Model name")),
                "unknown")


def commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True,
                              timeout=10).stdout.strip() or "unknown"
    except OSError:
        return "unknown"


if __name__ == "__main__":
    main()
