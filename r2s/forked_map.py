"""Run independent pieces of CPU-bound work in forked child processes.

PyBullet holds Python's global interpreter lock while it steps a world, so threads do not
run two worlds at once; forked processes do, and a fork shares the parent's memory (the
collision pieces, the parameters, the closures) without pickling it. Only each result
travels back, pickled through a pipe.

:func:`forked_map` is ``[fn(x) for x in items]`` with the same results in the same order,
computed up to :func:`cpu_budget` at a time. It falls back to computing in this process
where fork is unavailable, when the budget is one core, and for any item whose child did
not return a result (it died, or raised): the work is deterministic, so the fallback only
costs time. A child never runs the parent's exit handlers or flushes its buffers.
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
from typing import Callable, Iterable, Optional, Sequence, TypeVar

T = TypeVar("T")
R = TypeVar("R")

THREADS_VARIABLE = "OMP_NUM_THREADS"
"""Set by ``r2s batch`` to the cores each scene may use (r2s.runner.batch.cap_threads)."""


def cpu_budget() -> int:
    """The cores this process may use: ``$OMP_NUM_THREADS`` when it is a positive integer
    (a batch job's share), else the cores the process is allowed to run on."""
    value = os.environ.get(THREADS_VARIABLE, "").strip()
    if value.isdigit() and int(value) > 0:
        return int(value)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def forked_map(fn: Callable[[T], R], items: Iterable[T],
               workers: Optional[int] = None) -> list[R]:
    """``[fn(x) for x in items]``, with up to ``workers`` (default :func:`cpu_budget`)
    items at a time: the first of each group in this process, the others in forked
    children. ``fn``'s results must pickle."""
    todo = list(items)
    workers = cpu_budget() if workers is None else int(workers)
    if workers <= 1 or len(todo) <= 1 or not hasattr(os, "fork"):
        return [fn(x) for x in todo]
    out: list = []
    for start in range(0, len(todo), workers):
        out.extend(_group(fn, todo[start:start + workers]))
    return out


def _group(fn: Callable[[T], R], group: Sequence[T]) -> list[R]:
    children = [_fork_child(fn, x) for x in group[1:]]
    try:
        first = fn(group[0])
        results = [first]
        for x, child in zip(group[1:], children):
            ok, value = _collect(child)
            results.append(value if ok else fn(x))
        return results
    finally:
        for child in children:
            _reap(child)


def _fork_child(fn: Callable[[T], R], x: T) -> Optional[list]:
    """[pid, read end] of a child computing ``fn(x)``; None if fork failed."""
    read_fd, write_fd = os.pipe()
    try:
        pid = os.fork()
    except OSError:
        os.close(read_fd)
        os.close(write_fd)
        return None
    if pid == 0:  # the child: compute, write, leave without running anything of the parent's
        code = 1
        try:
            os.close(read_fd)
            signal.signal(signal.SIGINT, signal.SIG_DFL)
            _one_thread_in_child()
            payload = pickle.dumps(fn(x), protocol=pickle.HIGHEST_PROTOCOL)
            with os.fdopen(write_fd, "wb") as pipe:
                pipe.write(payload)
            code = 0
        except BaseException:  # noqa: BLE001  the parent recomputes the item
            pass
        finally:
            os._exit(code)
    os.close(write_fd)
    return [pid, read_fd]


def _one_thread_in_child() -> None:
    """A forked child computes on one core: the parent's share is already spread over its
    children, a ``forked_map`` inside runs in turn, and torch's OpenMP pool, whose threads
    the fork did not copy, would wait for them for ever (measured: a 2-thread ``exp`` in a
    child of a parent that had run one hangs)."""
    os.environ[THREADS_VARIABLE] = "1"
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


def _collect(child: Optional[list]) -> tuple[bool, object]:
    """(True, result) from a child that finished, else (False, None)."""
    if child is None:
        return False, None
    pid, read_fd = child
    chunks = []
    with os.fdopen(read_fd, "rb") as pipe:
        child[1] = None
        while True:
            chunk = pipe.read(1 << 16)
            if not chunk:
                break
            chunks.append(chunk)
    _, status = os.waitpid(pid, 0)
    child[0] = None
    if not (os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0):
        return False, None
    try:
        return True, pickle.loads(b"".join(chunks))
    except Exception:  # noqa: BLE001  a truncated payload: recompute
        return False, None


def _reap(child: Optional[list]) -> None:
    """Kill and wait for a child not collected (this process was interrupted)."""
    if child is None:
        return
    pid, read_fd = child
    if read_fd is not None:
        os.close(read_fd)
    if pid is not None:
        try:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        except (ProcessLookupError, ChildProcessError):
            pass
