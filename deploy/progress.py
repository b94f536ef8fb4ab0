"""The launcher's console progress line, from the dashboard's summary (``/api/status``).

A person reads it every 30 s: how long the run has been going, whether the learner trains yet
(and if not, what it waits for), how fast, and how well the greedy policy does, with the number
of episodes that percentage rests on.
"""

from __future__ import annotations

from typing import Optional


def duration(seconds: float) -> str:
    """``42s``, ``12m05s``, ``3h02m``."""
    s = int(max(0.0, seconds))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{s % 3600 // 60:02d}m"


def _count(value: Optional[float]) -> str:
    return f"{value:,.0f}" if value is not None else "?"


def progress_line(summary: dict, elapsed_s: float, min_size_to_sample: int, insecure: bool = False) -> str:
    """One line, e.g. ``12m05s | updates 412 (0.71/s) | env steps 3,120 (1,050 episodes) | ...``.

    ``insecure`` (plain TCP beyond loopback) leads the line, so nobody forgets it is on.
    """
    parts = (["INSECURE fabric"] if insecure else []) + [duration(elapsed_s)]
    updates, replay = summary.get("updates"), summary.get("replay_size")
    if not updates:
        if replay is not None and replay < min_size_to_sample:
            parts.append(
                f"learner waits: replay {_count(replay)}/{min_size_to_sample:,} transitions before training starts"
            )
        elif updates is None:
            parts.append("learner not reporting yet")
        else:
            parts.append("learner starting (first update on its way)")
    else:
        rate = summary.get("updates_per_s")
        parts.append(f"updates {_count(updates)}" + (f" ({rate:.2f}/s)" if rate is not None else ""))
    if summary.get("env_steps") is not None:
        parts.append(f"env steps {_count(summary['env_steps'])} ({_count(summary.get('episodes'))} episodes)")
    if replay is not None:
        spi = summary.get("samples_per_insert")
        parts.append(f"replay {_count(replay)}" + (f", {spi:.2f} samples per insert" if spi else ""))
    if summary.get("weights_version") is not None:
        parts.append(f"weights v{summary['weights_version']:.0f}")
    success = summary.get("eval_success")
    if success is None:
        parts.append("eval: none yet")
    else:
        episodes = summary.get("eval_episodes")
        of = f" of {episodes:.0f} episodes" if episodes is not None else ""
        parts.append(f"eval {100 * success:.0f}% success{of} (weights v{summary.get('eval_version', 0):.0f})")
    return " | ".join(parts)
