"""The person in the loop: success / fail / reset done / stop / resume, from the dashboard or a terminal.

Every source feeds one ``OperatorChannel``. ``stop`` and ``resume`` act at once, on the thread
that received them (a stop must not wait for the actor loop to look); the episode verdicts and
"reset done" are queued for the actor loop, which takes them when it is ready for them.

On a terminal a single key is enough (``x`` or space stops the arm as the key goes down, no
Enter); from a pipe or a file, one word per line.
"""

from __future__ import annotations

import atexit
import contextlib
import logging
import os
import select
import termios
import threading
import time
import tty
from collections import deque
from collections.abc import Callable
from typing import IO

from protocol import keys
from protocol.codec import ProtocolError
from protocol.messages import OperatorAction, OperatorCommand, decode

log = logging.getLogger("robot.operator")

#: Terminal words (first letter is enough) for each action, one per line when stdin is not a terminal.
TERMINAL_WORDS = {"s": OperatorAction.SUCCESS, "f": OperatorAction.FAIL, "r": OperatorAction.RESET_DONE,
                  "x": OperatorAction.STOP, "c": OperatorAction.RESUME}
#: Single keys on a terminal: the words' first letters, and space (the largest key) also stops.
TERMINAL_KEYS = {**TERMINAL_WORDS, " ": OperatorAction.STOP}
TERMINAL_HELP = "operator keys: [s]uccess  [f]ail  [r]eset done  [x] or space: stop  [c]ontinue (resume)"
LINE_HELP = "operator: [s]uccess  [f]ail  [r]eset done  [x] stop  [c]ontinue (resume), then Enter"


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


class _Cbreak:
    """A terminal in cbreak mode (each key is read at once, without echo; Ctrl-C still signals) until restored."""

    def __init__(self, fd: int) -> None:
        self.fd, self._saved = fd, termios.tcgetattr(fd)
        self._lock = threading.Lock()
        tty.setcbreak(fd, termios.TCSANOW)

    def restore(self) -> None:
        """The settings found at the start, once; a terminal already gone is left alone."""
        with self._lock:
            saved, self._saved = self._saved, None
            if saved is not None:
                with contextlib.suppress(termios.error, OSError):
                    termios.tcsetattr(self.fd, termios.TCSANOW, saved)


def _key_terminal(stream: IO[str]) -> int | None:
    """The stream's descriptor when it is a terminal to read single keys from; None for line mode.

    A background job keeps line mode: changing its terminal's settings would stop it (SIGTTOU).
    """
    try:
        if not stream.isatty():
            return None
        fd = stream.fileno()
    except (AttributeError, OSError, ValueError):
        return None
    try:
        if os.tcgetpgrp(fd) != os.getpgrp():
            return None
    except OSError:
        pass  # not this process's controlling terminal: no job control applies
    return fd


class TerminalOperator:
    """Operator commands from the robot actor's terminal: a single keypress on a TTY, a word a line otherwise.

    On a TTY the terminal is put in cbreak mode, so a stop acts on the key itself, not on Enter;
    ``close()`` (or leaving ``with``) restores its settings, and so does the reader ending.
    Pipes, files and services (stdin not a TTY) keep line mode.
    """

    def __init__(self, stream: IO[str], channel: OperatorChannel) -> None:
        self.channel = channel
        self._closed = threading.Event()
        fd = _key_terminal(stream)
        self._cbreak = _Cbreak(fd) if fd is not None else None
        self.help = TERMINAL_HELP if self._cbreak else LINE_HELP
        if self._cbreak:
            atexit.register(self.close)  # a normal interpreter exit that skipped close()
            reader, source = self._read_keys, fd
        else:
            reader, source = self._read_lines, stream
        self._thread = threading.Thread(target=reader, args=(source,), name="operator-terminal", daemon=True)
        self._thread.start()

    def __enter__(self) -> TerminalOperator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop reading keys and give the terminal its settings back (line mode: nothing to undo)."""
        self._closed.set()
        if self._cbreak:
            self._thread.join(timeout=1.0)
            self._cbreak.restore()
            atexit.unregister(self.close)

    def _read_keys(self, fd: int) -> None:
        try:
            while not self._closed.is_set():
                try:
                    if not select.select([fd], [], [], 0.2)[0]:
                        continue
                    data = os.read(fd, 64)
                except (OSError, ValueError):  # the terminal hung up or was closed
                    return
                if not data:
                    return
                self._on_keys(data.decode(errors="replace").lower())
        finally:
            self._cbreak.restore()  # nobody reads keys any more: the terminal is the operator's again

    def _on_keys(self, keys_pressed: str) -> None:
        unknown = False
        for key in keys_pressed:
            action = TERMINAL_KEYS.get(key)
            if action is not None:
                self._put(action)
                print(f"operator: {action.value}", flush=True)  # the key is not echoed: say what it did
            elif key not in "\r\n":
                unknown = True
        if unknown:
            print(self.help, flush=True)

    def _read_lines(self, stream: IO[str]) -> None:
        for line in stream:
            if self._closed.is_set():
                return
            word = line.strip().lower()
            action = TERMINAL_WORDS.get(word[:1]) if word else None
            if action is None:
                if word:
                    print(self.help, flush=True)
                continue
            self._put(action)

    def _put(self, action: OperatorAction) -> None:
        """Hand the action on; a failure is logged and the next key still counts (the reader must live on)."""
        try:
            self.channel.put(action, "terminal")
        except Exception:
            log.exception("operator (terminal): %s failed", action.value)
