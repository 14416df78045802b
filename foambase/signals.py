"""Interruptions (SIGINT, SIGTERM) as exceptions, and temporary files that are removed on every rank when one arrives.

Inside :func:`interruptible` (the command lines run every command in it), SIGINT and SIGTERM raise
:class:`Interrupted` in the main thread, so that every ``finally`` block and every writer's clean-up runs for a
SIGTERM as it does for a Ctrl-C, and the command exits with ``128 + signal number`` (130 for SIGINT, 143 for
SIGTERM). Under ``mpirun`` a Ctrl-C reaches every rank as a SIGTERM.

Python runs a signal handler only when the main thread executes Python code; a rank that waits inside MPI for a rank
that has already stopped never does (``mpirun`` kills it about a second later). Temporary files and directories are
therefore also registered here (:func:`register_temporary`; :func:`foambase.files.atomic_path` and the scene's XDMF
series do), and a watcher thread, woken by the signal itself (``signal.set_wakeup_fd``), removes them on every
rank ``GRACE_S`` after a signal unless the main thread has taken over by then; when the main thread has, the
interruption removes whatever is still registered as it leaves :func:`interruptible`.
"""

from __future__ import annotations

import contextlib
import os
import select
import shutil
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path

__all__ = ["GRACE_S", "Interrupted", "discard_temporary", "interruptible", "register_temporary",
           "remove_temporaries"]

#: Seconds the watcher thread leaves the main thread to react to a signal before it removes the temporaries.
GRACE_S = 0.3
_SIGNALS = (signal.SIGINT, signal.SIGTERM)

_lock = threading.Lock()
_temporaries: dict[Path, None] = {}
_main_reacted = threading.Event()


class Interrupted(KeyboardInterrupt):
    """A SIGINT or SIGTERM received inside :func:`interruptible`; ``exit_code`` is ``128 + signum``."""

    def __init__(self, signum: int):
        self.signum = int(signum)
        self.signal_name = signal.Signals(signum).name
        self.exit_code = 128 + self.signum
        super().__init__(f"interrupted by {self.signal_name}")

    def __reduce__(self):
        return type(self), (self.signum,)


def register_temporary(path: str | os.PathLike) -> None:
    """Remember a temporary file or directory, to be removed if a signal arrives (:func:`interruptible`)."""
    with _lock:
        _temporaries[Path(path)] = None


def discard_temporary(path: str | os.PathLike) -> None:
    """Forget a temporary registered by :func:`register_temporary` (it was moved into place or removed)."""
    with _lock:
        _temporaries.pop(Path(path), None)


def remove_temporaries() -> None:
    """Remove every registered temporary (files and directory trees; missing ones are skipped)."""
    with _lock:
        paths = list(_temporaries)
        _temporaries.clear()
    for path in paths:
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                path.unlink()


def _raise(signum: int, frame) -> None:
    _main_reacted.set()
    raise Interrupted(signum)


def _watch(fd: int, stop: threading.Event) -> None:
    while not stop.is_set():
        ready, _, _ = select.select([fd], [], [], 1.0)
        if not ready:
            continue
        try:
            data = os.read(fd, 64)
        except OSError:
            return
        if stop.is_set():
            return
        if any(byte in _SIGNALS for byte in data):
            time.sleep(GRACE_S)
            if not _main_reacted.is_set():  # the main thread is stuck (e.g. waiting in MPI): clean up for it
                remove_temporaries()


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """SIGINT and SIGTERM raise :class:`Interrupted` inside the block; registered temporaries are removed on a signal.

    Outside the main thread (where Python cannot install handlers) the block runs unchanged.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)
    previous_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    previous = {s: signal.signal(s, _raise) for s in _SIGNALS}
    _main_reacted.clear()
    stop = threading.Event()
    watcher = threading.Thread(target=_watch, args=(read_fd, stop), name="fenicsfoam-signals", daemon=True)
    watcher.start()
    try:
        yield
    except KeyboardInterrupt:
        remove_temporaries()  # whatever the unwinding code did not remove itself
        raise
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        signal.set_wakeup_fd(previous_fd)
        stop.set()
        with contextlib.suppress(OSError):
            os.write(write_fd, b"\0")  # wake the watcher
        watcher.join(timeout=2.0)
        os.close(write_fd)
        if not watcher.is_alive():
            os.close(read_fd)
