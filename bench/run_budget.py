"""Running one ``c2farm launch`` under a wall-clock budget that survives restarts of the bench.

``runs/<id>/bench_budget.json`` records the wall-clock segments the bench has given a run (written
every 30 s, so a killed bench loses at most that much), so a rerun only spends what is left and
curve minutes count only those segments: a run resumed the next day is not stretched by the time
it lay idle. It also records the rate a run held when the bench stopped it (``--stop-at``).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional, Sequence

BUDGET_FILE = "bench_budget.json"


@dataclass
class Budget:
    """Wall-clock [start, end] segments the bench has given one run, one per bench launch."""

    segments: list[list[float]] = field(default_factory=list)
    #: the success rate the run held when the bench stopped it (``--stop-at``); None while it has not
    held_rate: Optional[float] = None

    @property
    def spent(self) -> float:
        return sum(max(0.0, end - start) for start, end in self.segments)

    def remaining(self, budget_s: float) -> float:
        return max(0.0, budget_s - self.spent)


def load_budget(run_dir: Path) -> Budget:
    """The run's bookkeeping; empty for a run the bench never ran (or launched by hand)."""
    try:
        data = json.loads((run_dir / BUDGET_FILE).read_text())
    except (FileNotFoundError, ValueError):
        return Budget()
    held = data.get("held_rate")
    return Budget([[float(start), float(end)] for start, end in data.get("segments", [])],
                  None if held is None else float(held))


def save_budget(run_dir: Path, budget: Budget) -> None:
    """Write atomically, so a bench killed mid-write leaves the previous bookkeeping intact."""
    tmp = run_dir / (BUDGET_FILE + ".tmp")
    tmp.write_text(json.dumps({"spent_s": round(budget.spent, 3), "segments": budget.segments,
                               "held_rate": budget.held_rate}) + "\n")
    os.replace(tmp, run_dir / BUDGET_FILE)


def active_seconds(t: float, launched_at: float, segments: Sequence[Sequence[float]]) -> float:
    """Seconds the run had been running at wall time t: gaps between bench segments left out.

    Without bookkeeping this is ``t - launched_at``, as the launcher counts; time before the
    first segment (a run launched by hand, then benched) counts in full.
    """
    if not segments:
        return t - launched_at
    total = max(0.0, min(t, segments[0][0]) - launched_at)
    for start, end in segments:
        total += max(0.0, min(t, end) - max(start, launched_at))
    return total + max(0.0, t - segments[-1][1])  # after the last progress write (a killed bench)


def mark_held(run_dir: Path, rate: float) -> None:
    """Record that the bench stopped this run because it held ``rate``: its curve is then complete."""
    budget = load_budget(run_dir)
    budget.held_rate = rate
    save_budget(run_dir, budget)


def stop(proc: subprocess.Popen) -> None:
    """SIGTERM the launcher's process group (it stops every role within 10 s), then insist.

    SIGTERM, not SIGINT: a bench started in the background (``nohup ... &``) inherits an
    ignored SIGINT, and then nothing would stop.
    """
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=60)
    except ProcessLookupError:
        pass
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def run_budgeted(cmd: Sequence[str], run_dir: Path, budget_s: float, progress_every: float = 30.0,
                 done: Optional[Callable[[], bool]] = None) -> Optional[int]:
    """Run cmd until the run has had budget_s seconds over all bench launches, or ``done()``.

    Returns the exit code if it ended by itself, None if the bench stopped it (or had no time
    left). The spent time is saved every progress_every seconds and on the way out, Ctrl-C
    included, so a rerun picks up where this one stopped.
    """
    run_dir.mkdir(parents=True, exist_ok=True)
    budget = load_budget(run_dir)
    if budget.remaining(budget_s) <= 0:
        return None
    now = time.time()
    budget.segments.append([now, now])
    save_budget(run_dir, budget)
    code: Optional[int] = None
    proc = subprocess.Popen(list(cmd), start_new_session=True)
    try:
        while code is None and budget.remaining(budget_s) > 0:
            try:
                code = proc.wait(timeout=min(progress_every, budget.remaining(budget_s)))
            except subprocess.TimeoutExpired:
                pass
            budget.segments[-1][1] = time.time()
            save_budget(run_dir, budget)
            if code is None and done is not None and done():
                break
    finally:
        budget.segments[-1][1] = time.time()
        save_budget(run_dir, budget)
        if code is None:
            stop(proc)
            budget.segments[-1][1] = time.time()  # shutdown counts too: the run held the machine
            save_budget(run_dir, budget)
    return code


#: A bounded busy loop: spins until its deadline (seconds since the epoch), then exits by itself.
HOG = "import sys, time\nend = float(sys.argv[1])\nwhile time.time() < end:\n    pass\n"


@contextlib.contextmanager
def cpu_hog(cores: int, seconds: float):
    """Keep ``cores`` cores busy for at most ``seconds`` (the busy-machine condition), then stop."""
    deadline = time.time() + seconds + 120  # a hog left behind by a killed bench still ends by itself
    hogs = [subprocess.Popen([sys.executable, "-c", HOG, str(deadline)]) for _ in range(cores)]
    try:
        yield
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
