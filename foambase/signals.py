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

A main thread busy in one long call of compiled code (a sparse factorization, a large assembly) does not run Python
for minutes, so the watcher also ends the process for it: ``FORCE_S`` after the signal, if the main thread has still
not reacted, the last-resort actions registered with :func:`register_last_resort` run in the watcher thread (a scene
run marks its ``summary.json`` interrupted and prints the steps done, then the command line prints its usual
"interrupted by SIGNAL" line) and the process exits with ``128 + signal
number`` at once (``os._exit``).
"""

from __future__ import annotations

import contextlib
import os
import select
import shutil
import signal
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

__all__ = ["FORCE_S", "GRACE_S", "Interrupted", "discard_last_resort", "discard_temporary", "interruptible",
           "register_last_resort", "register_temporary", "remove_temporaries"]

#: Seconds the watcher thread leaves the main thread to react to a signal before it removes the temporaries.
GRACE_S = 0.3
#: Seconds after a signal at which a main thread that has not reacted is ended by the watcher (module docstring).
FORCE_S = 5.0
_SIGNALS = (signal.SIGINT, signal.SIGTERM)

_lock = threading.Lock()
_temporaries: dict[Path, None] = {}
_main_reacted = threading.Event()
_last_resort: list[Callable[[str], None]] = []


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


def register_last_resort(action: Callable[[str], None]) -> None:
    """Run ``action(signal name)`` in the watcher thread if the main thread is stuck ``FORCE_S`` after a signal.

    The actions run in the reverse order of their registration (the last registered first), as exit handlers do.
    """
    with _lock:
        _last_resort.append(action)


def discard_last_resort(action: Callable[[str], None]) -> None:
    """Forget an action of :func:`register_last_resort`."""
    with _lock:
        if action in _last_resort:
            _last_resort.remove(action)


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
        received = [byte for byte in data if byte in _SIGNALS]
        if received:
            if _main_reacted.wait(GRACE_S) or stop.is_set():
                continue
            remove_temporaries()  # the main thread is stuck (e.g. waiting in MPI): clean up for it
            if _main_reacted.wait(FORCE_S - GRACE_S) or stop.is_set():
                continue
            name = signal.Signals(received[0]).name
            with _lock:
                actions = list(reversed(_last_resort))  # the innermost first: a command's closing line comes last
            for action in actions:
                try:
                    action(name)
                except Exception:  # noqa: BLE001 - the process ends anyway; the others still run
                    pass
            os._exit(128 + received[0])


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
