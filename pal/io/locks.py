"""A single-writer lock for a directory: an ``O_EXCL``-created JSON lock file.

The lock file (``writer.lock`` by default) holds the writer's pid, host, start time and a
random token. Creating it with ``O_CREAT | O_EXCL`` succeeds for exactly one process, so a
second writer is refused with :class:`DirectoryLockedError` naming the directory and the
holder.

Stale locks: a lock left by a writer that was killed (same host, pid no longer running) is
**taken over with a logged warning**, so ``pal babble --resume`` works after a crash without
manual cleanup. Takeovers are serialised by an ``flock`` on the directory and re-read the
lock under it, so two processes cannot both take over the same stale lock. A lock file that
is still empty (its writer is between creating and filling it) is re-read for up to 1 s. A
lock held on another host, or one whose content is unreadable, cannot be judged and is
refused with a message that says how to remove it. POSIX only (``fcntl``).
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import socket
import time
import uuid
from pathlib import Path
from typing import Any

from pal.io.files import FILE_MODE

__all__ = ["LOCK_NAME", "DirectoryLock", "DirectoryLockedError", "pid_alive"]

logger = logging.getLogger(__name__)

LOCK_NAME = "writer.lock"


class DirectoryLockedError(ValueError):
    """Another writer holds the directory's lock (or its lock cannot be judged)."""


def pid_alive(pid: int) -> bool:
    """True if a process with this pid runs on this host (or exists under another user)."""
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, OverflowError):  # OverflowError: past any pid the kernel gives
        return False
    except PermissionError:
        return True
    return True


class DirectoryLock:
    """Exclusive write access to ``directory`` for this process; a context manager.

    Args:
        directory: the directory to lock (created if needed).
        name: the lock file's name inside it.

    Attributes:
        path: the lock file.
        held: whether this object holds the lock.
    """

    def __init__(self, directory: str | os.PathLike[str], name: str = LOCK_NAME) -> None:
        self.directory = Path(directory)
        self.path = self.directory / name
        self.held = False
        self._token = uuid.uuid4().hex

    def __repr__(self) -> str:
        return f"DirectoryLock({str(self.path)!r}, held={self.held})"

    def _create(self) -> None:
        fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, FILE_MODE)
        try:
            os.fchmod(fd, FILE_MODE)  # O_CREAT's mode is filtered by the umask
            info = {
                "pid": os.getpid(),
                "host": socket.gethostname(),
                "since": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                "token": self._token,
            }
            os.write(fd, (json.dumps(info, sort_keys=True) + "\n").encode())
            os.fsync(fd)
        finally:
            os.close(fd)
        self.held = True

    def holder(self) -> dict[str, Any] | None:
        """The lock file's content, or None if it is missing or unreadable."""
        try:
            info = json.loads(self.path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return None
        except (OSError, UnicodeDecodeError, ValueError) as err:
            logger.debug("lock file %s is unreadable: %s", self.path, err)
            return None
        ok = isinstance(info, dict) and isinstance(info.get("pid"), int) and isinstance(info.get("host"), str)
        return info if ok and info["pid"] > 0 else None

    def _settled_holder(self, wait: float = 1.0) -> dict[str, Any] | None:
        """:meth:`holder`, re-read for up to ``wait`` s while the file is empty (being written)."""
        deadline = time.monotonic() + wait
        while True:
            info = self.holder()
            if info is not None or time.monotonic() > deadline:
                return info
            try:
                if self.path.stat().st_size > 0:
                    return self.holder()  # filled since the read above, or invalid for good
            except FileNotFoundError:
                return None
            time.sleep(0.01)

    def acquire(self) -> DirectoryLock:
        """Take the lock (see the module docstring for stale locks).

        Raises:
            DirectoryLockedError: a live writer holds it, or the holder cannot be judged.
        """
        if self.held:
            return self
        self.directory.mkdir(parents=True, exist_ok=True)
        try:
            self._create()
            return self
        except FileExistsError:
            pass
        guard = os.open(self.directory, os.O_RDONLY)
        try:
            fcntl.flock(guard, fcntl.LOCK_EX)  # serialises takeovers; released with the fd
            try:
                self._create()  # the holder may have released it meanwhile
                return self
            except FileExistsError:
                pass
            info = self._settled_holder()
            if info is None:
                raise DirectoryLockedError(
                    f"{self.directory} is locked by {self.path}, whose content is unreadable (a writer is "
                    f"creating it, or crashed while doing so); if no process writes to {self.directory}, "
                    f"delete {self.path} and retry"
                )
            who = f"pid {info['pid']} on host {info['host']!r} (since {info.get('since', '?')})"
            if info["host"] != socket.gethostname():
                raise DirectoryLockedError(
                    f"{self.directory} is being written by {who}; if that process no longer runs, "
                    f"delete {self.path} and retry"
                )
            if pid_alive(info["pid"]):
                raise DirectoryLockedError(
                    f"{self.directory} is being written by {who}; only one writer may write a "
                    "directory at a time: wait for it to finish or stop it"
                )
            logger.warning("taking over the stale lock %s of %s: that process no longer runs", self.path, who)
            self.path.unlink()
            try:
                self._create()
            except FileExistsError:
                raise DirectoryLockedError(
                    f"{self.directory} was locked by another writer while taking over a stale lock; "
                    f"its holder is {self.holder()}"
                ) from None
        finally:
            os.close(guard)
        return self

    def release(self) -> None:
        """Remove the lock file if this object holds it (idempotent)."""
        if not self.held:
            return
        self.held = False
        info = self.holder()
        if info is None or info.get("token") != self._token:
            logger.warning("lock %s is no longer this writer's (holder %s); leaving it", self.path, info)
            return
        self.path.unlink(missing_ok=True)

    def __enter__(self) -> DirectoryLock:
        return self.acquire()

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        self.release()
