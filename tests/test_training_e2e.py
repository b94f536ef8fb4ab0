"""The whole system trains: demos and episodes flow into the replay, the learner updates,
actors pick up newer weights, and a learner killed mid-run resumes from its checkpoint.

Every role is a real process started by `c2farm launch`; the networks are shrunk so a
2-core CI machine does a few updates a second.
"""

from __future__ import annotations

import os
import re
import signal
from pathlib import Path

import httpx
from conftest import kill_launcher, small_launch, status_reader, stop_launcher, wait_for

from learner.checkpoint import complete_checkpoints

RESUMED = re.compile(r"resumed from checkpoint at step (\d+)")


def test_distributed_training_runs_and_the_learner_resumes_after_a_kill(tmp_path: Path):
    launcher, lines, children, dashboard = small_launch("e2e", tmp_path)

    run_dir = tmp_path / "runs" / "e2e"
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{dashboard}", timeout=5) as http:

            status = status_reader(http, children)

            # Demos and live episodes reach the replay, the learner updates, the actor swaps weights.
            first = wait_for(
                lambda: (s := status()) and (s["summary"]["updates"] or 0) >= 6
                and s.get("actor-0", {}).get("counters", {}).get("weights_version", 0) >= 2 and s,
                300, "learner updates and a newer weights version at the actor",
            )
            assert first["summary"]["env_steps"] > 0 and first["summary"]["replay_size"] >= 8
            assert first["demos"]["counters"]["demo_episodes"] > 0
            assert first["actor-0"]["counters"]["acked"] > 0
            assert "actor-0" in first["summary"]["policy_lag"]

            # Kill the learner outright; the launcher restarts it and it resumes its step.
            victim = first["learner"]["pid"]
            os.kill(victim, signal.SIGKILL)
            saved = complete_checkpoints(run_dir / "checkpoints" / "learner")
            assert saved, "the learner wrote no checkpoint before the kill"
            saved_step = int(saved[-1].name.removeprefix("step-"))
            back = wait_for(
                lambda: (s := status()) and s["learner"]["alive"] and s["learner"]["pid"] not in (None, victim)
                and s["learner"]["counters"].get("updates") is not None and s,
                180, "the learner to be restarted",
            )
            assert back["learner"]["counters"]["updates"] >= saved_step
            resumed = wait_for(lambda: [int(m[1]) for line in lines if (m := RESUMED.search(line))],
                               30, "the restarted learner to say it resumed")
            assert resumed[-1] >= saved_step
            version_before = back["learner"]["counters"]["weights_version"]
            wait_for(
                lambda: (
                    (s := status()) and s["learner"]["counters"]["updates"] > back["learner"]["counters"]["updates"]
                ),
                180,
                "the resumed learner to keep updating",
            )
            assert status()["learner"]["counters"]["weights_version"] >= version_before  # versions never go back
            # the console's progress line (every 5 s here), from the dashboard's summary
            wait_for(lambda: any(re.search(r"progress: \S+ \| updates [\d,]+", line) for line in lines), 60,
                     "a progress line on the console")
            # the evaluator has evaluated a version (eval.csv and TensorBoard get it)
            wait_for(lambda: (s := status()) and s.get("eval", {}).get("counters", {}).get("eval_version", 0) >= 1,
                     300, "an evaluation")

        stop_launcher(launcher, children)
    finally:
        kill_launcher(launcher, children)

    assert (run_dir / "metrics" / "learner.csv").exists()
    assert (run_dir / "metrics" / "eval.csv").exists()
    assert list((run_dir / "tensorboard").glob("events.out.tfevents.*.eval")), "no evaluation scalars in TensorBoard"
