"""One writer per scene directory: an OS-level lock on ``<scene>/.r2s-lock``.

The lock is an exclusive :func:`fcntl.flock` on the lock file, held for as long as a
command writes the scene. The kernel drops it when the holding process ends, however it
ends (``kill -9`` included), so a lock left by a killed run is taken over by the next one
without any clean-up; the file's text (pid, host, start time, command) only tells a
waiting process who holds the lock and, once it is free, who held it last.

The lock is re-entrant within a process (a command that runs several stages takes it once
per stage without deadlocking on itself). A second process either fails at once with one
line naming the holder (:class:`SceneBusyError`) or, with ``wait_s > 0``, waits up to that
long, saying once that it is waiting.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Iterator, Optional

from r2s.errors import InputError, R2SError

LOCK_NAME = ".r2s-lock"
"""The lock file inside the scene directory (hidden: no stage hashes it)."""

POLL_S = 0.2
"""How often a waiting process retries the lock."""


class SceneBusyError(R2SError):
    """Another process writes this scene directory."""

    exit_code = 4


class SceneNotWritableError(R2SError):
    """The scene directory cannot be written (read-only file system or permissions)."""

    exit_code = 2


@dataclass(frozen=True)
class LockHolder:
    """Who holds (or last held) a scene lock, as written in the lock file."""

    pid: int
    host: str
    since: str
    command: str = ""

    def describe(self) -> str:
        cmd = f" ({self.command})" if self.command else ""
        return f"pid {self.pid} on {self.host} since {self.since}{cmd}"

    def is_dead_here(self) -> bool:
        """True when the holder ran on this host and its pid no longer exists."""
        if self.host != socket.gethostname():
            return False
        try:
            os.kill(self.pid, 0)
        except ProcessLookupError:
            return True
        except PermissionError:
            return False
        return False


def read_holder(lock_path: Path) -> Optional[LockHolder]:
    """The holder recorded in ``lock_path``, or None if it is empty or unreadable."""
    try:
        data = json.loads(Path(lock_path).read_text())
        return LockHolder(pid=int(data["pid"]), host=str(data["host"]), since=str(data["since"]),
                          command=str(data.get("command", "")))
    except (OSError, ValueError, KeyError, TypeError):
        return None


_held: dict[Path, list] = {}  # resolved scene dir -> [fd, depth]
_held_guard = threading.Lock()


def _open_lock_file(scene_dir: Path) -> int:
    lock_path = scene_dir / LOCK_NAME
    if not scene_dir.is_dir():
        raise InputError(scene_dir, "scene directory does not exist")
    try:
        return os.open(lock_path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        if exc.errno in (13, 30):  # EACCES, EROFS
            raise SceneNotWritableError(
                f"{scene_dir}: scene directory is not writable ({exc.strerror.lower()}); r2s "
                "writes its stage folders and manifest.json next to input/ - copy the scene "
                "to a writable place") from None
        raise


def _write_holder(fd: int, command: str) -> None:
    text = json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                       "since": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                       "command": command})
    data = text.encode()
    os.pwrite(fd, data, 0)  # write first, then cut: the file is never empty while held
    os.ftruncate(fd, len(data))


HOLDER_READ_WAIT_S = 2.0
"""How long a refused process waits for the new holder to write its name into the lock file
(the holder takes the lock a moment before it writes the file)."""


def _describe_busy(scene_dir: Path) -> str:
    deadline = time.monotonic() + HOLDER_READ_WAIT_S
    holder = read_holder(scene_dir / LOCK_NAME)
    while holder is None and time.monotonic() < deadline:
        time.sleep(0.05)
        holder = read_holder(scene_dir / LOCK_NAME)
    who = holder.describe() if holder is not None else "another process"
    return f"{scene_dir}: scene is being written by {who}"


@contextmanager
def scene_lock(scene_dir: Path, wait_s: float = 0.0, command: str = "",
               notify: Callable[[str], None] = lambda message: None) -> Iterator[None]:
    """Hold the scene's write lock for the ``with`` block.

    ``wait_s``: 0 fails at once with :class:`SceneBusyError` when another process holds it;
    > 0 waits up to that many seconds (``notify`` is told once that it waits, and once if it
    takes over the lock of a process that no longer runs). ``command`` is recorded for the
    message other processes print.
    """
    scene_dir = Path(scene_dir).resolve()
    with _held_guard:
        entry = _held.get(scene_dir)
        if entry is not None:
            entry[1] += 1
    if entry is not None:  # re-entrant: this process already holds it
        try:
            yield
        finally:
            with _held_guard:
                entry[1] -= 1
        return

    fd = _open_lock_file(scene_dir)
    previous = read_holder(scene_dir / LOCK_NAME)
    deadline = time.monotonic() + max(0.0, wait_s)
    told = False
    try:
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    hint = (f"; gave up after waiting {wait_s:g} s" if wait_s > 0
                            else "; wait for it to finish or pass --wait SECONDS")
                    raise SceneBusyError(_describe_busy(scene_dir) + hint) from None
                if not told:
                    notify(_describe_busy(scene_dir) + f"; waiting up to {wait_s:g} s")
                    told = True
                time.sleep(POLL_S)
        if previous is not None and previous.pid != os.getpid() and previous.is_dead_here():
            notify(f"{scene_dir}: taking over the lock left by pid {previous.pid} "
                   f"(since {previous.since}; no longer running)")
        _write_holder(fd, command or ("r2s " + sys.argv[1] if len(sys.argv) > 1 else "r2s"))
    except BaseException:
        os.close(fd)
        raise
    with _held_guard:
        _held[scene_dir] = [fd, 1]
    try:
        yield
    finally:
        with _held_guard:
            _held.pop(scene_dir, None)
        try:
            os.ftruncate(fd, 0)  # nobody holds it now
        except OSError:
            pass
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


def holds_lock(scene_dir: Path) -> bool:
    """Whether this process holds the scene's lock now."""
    with _held_guard:
        return Path(scene_dir).resolve() in _held
