"""The person in the loop: success / fail / reset done / stop / resume, from the dashboard or a terminal.

Every source feeds one ``OperatorChannel``. ``stop`` and ``resume`` act at once, on the thread
that received them (a stop must not wait for the actor loop to look); the episode verdicts and
"reset done" are queued for the actor loop, which takes them when it is ready for them.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import IO

from protocol import keys
from protocol.codec import ProtocolError
from protocol.messages import OperatorAction, OperatorCommand, decode

log = logging.getLogger("robot.operator")

#: Terminal words (first letter is enough) for each action.
TERMINAL_WORDS = {"s": OperatorAction.SUCCESS, "f": OperatorAction.FAIL, "r": OperatorAction.RESET_DONE,
                  "x": OperatorAction.STOP, "c": OperatorAction.RESUME}
TERMINAL_HELP = "operator: [s]uccess  [f]ail  [r]eset done  [x] stop  [c]ontinue (resume), then Enter"


class OperatorChannel:
    """Operator commands for one robot actor, from every source, in arrival order."""

    def __init__(self, on_stop: Callable[[], object] = lambda: None, on_resume: Callable[[], object] = lambda: None):
        self._on_stop, self._on_resume = on_stop, on_resume
        self._queue: deque[OperatorAction] = deque()
        self._cond = threading.Condition()
        self.paused = False
        self.counters: dict[str, float] = {}

    def put(self, action: OperatorAction, source: str = "") -> None:
        action = OperatorAction(action)
        log.info("operator (%s): %s", source or "?", action.value)
        self.counters[f"operator_{action.value}"] = self.counters.get(f"operator_{action.value}", 0) + 1
        if action is OperatorAction.STOP:
            self.paused = True
            self._on_stop()
        elif action is OperatorAction.RESUME:
            self.paused = False
            self._on_resume()
        with self._cond:
            if action not in (OperatorAction.STOP, OperatorAction.RESUME):
                self._queue.append(action)
            self._cond.notify_all()

    def take(self, wanted: set[OperatorAction]) -> OperatorAction | None:
        """The oldest queued command among ``wanted`` (removed), or None; never waits."""
        with self._cond:
            for action in self._queue:
                if action in wanted:
                    self._queue.remove(action)
                    return action
        return None

    def wait_for(self, wanted: set[OperatorAction], stop: threading.Event, timeout_s: float | None = None
                 ) -> OperatorAction | None:
        """Block until one of ``wanted`` arrives while not paused; None on ``stop`` or timeout."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not stop.is_set():
            if not self.paused:
                action = self.take(wanted)
                if action is not None:
                    return action
            left = 0.2 if deadline is None else min(0.2, deadline - time.monotonic())
            if left <= 0:
                return None
            with self._cond:
                self._cond.wait(left)
        return None

    def wait_resumed(self, stop: threading.Event) -> bool:
        """Block while paused; False when ``stop`` came first."""
        while self.paused and not stop.is_set():
            with self._cond:
                self._cond.wait(0.2)
        return not stop.is_set()

    def discard(self, actions: set[OperatorAction]) -> None:
        """Forget queued commands of these kinds (a verdict left over from an earlier episode)."""
        with self._cond:
            kept = [a for a in self._queue if a not in actions]
            self._queue.clear()
            self._queue.extend(kept)


class FabricOperator:
    """Feeds a channel from ``OperatorCommand``s put on ``c2farm/<run>/operator/<instance>`` (the dashboard)."""

    def __init__(self, session, run_id: str, instance: str, channel: OperatorChannel) -> None:
        self.instance, self.channel, self.rejected = instance, channel, 0
        self._subscriber = session.declare_subscriber(keys.operator(run_id, instance), self._on_sample)

    def _on_sample(self, sample) -> None:
        try:
            command = decode(bytes(sample.payload.to_bytes()), expect=OperatorCommand)
        except ProtocolError as exc:
            self.rejected += 1
            log.warning("rejected an operator message: %s", exc)
            return
        if command.actor != self.instance:
            self.rejected += 1
            return
        self.channel.put(command.action, command.source or "fabric")

    def close(self) -> None:
        self._subscriber.undeclare()


class TerminalOperator:
    """Reads operator words from a text stream (the robot actor's terminal), one per line."""

    def __init__(self, stream: IO[str], channel: OperatorChannel) -> None:
        self.channel = channel
        self._thread = threading.Thread(target=self._read, args=(stream,), name="operator-terminal", daemon=True)
        self._thread.start()

    def _read(self, stream: IO[str]) -> None:
        for line in stream:
            word = line.strip().lower()
            action = TERMINAL_WORDS.get(word[:1]) if word else None
            if action is None:
                if word:
                    print(TERMINAL_HELP, flush=True)
                continue
            self.channel.put(action, "terminal")
