"""Outputs appear complete or not at all, one run at a time per folder.

Files are written into a hidden staging folder inside the destination
(``.partial-<pid>-*``) and moved into place (``os.replace``) only when every writer has
finished; an exception or Ctrl-C removes the staging folder and leaves earlier outputs
intact.  A run owns its output set: files of the set (by name pattern) that it does not
write this time are removed, and logged, so an earlier run's ``points.las`` never sits
next to a new ``scan.exr``; other files are never touched.

A run *claims* its folder (:func:`claim_output`, or the :func:`writes_output` decorator
on a run function, before any work): the location is checked (a folder, or creatable,
and writable: :class:`~simlidar_mi.errors.OutputError` otherwise), a lock file
``.simlidar-mi.lock`` naming the process is taken (``flock``: released by the kernel
when the process dies, even by SIGKILL), so a second run into the same folder is
refused rather than interleaved, and staging folders and temporary files left by a
killed run (their pid is in the name, and dead) are removed.  Forked children close
their copy of the lock (:func:`forget_claims_after_fork`); a lock still held although
the process it names on this host is gone (an orphan that inherited it) is taken over,
with a warning.

Links are never followed in the folder: the lock file is opened with ``O_NOFOLLOW`` and
must be a regular file with one link (else :class:`OutputError`, one line), temporary files
are made with ``O_EXCL`` and renamed over whatever name is there (a symbolic link at an
output's name is replaced, never written through), and removals unlink names.  Only
outputs that an earlier run here recorded as its own are removed: each file or folder a run
moves into place carries the extended attribute ``user.simlidar-mi.output`` with its size
and modification time; one whose record is missing or no longer matches (a user's file of
the same name, one changed since, a file system without extended attributes) is left where
it is, with a one-line note.  (The output folder given by the user may itself be a link: it
is resolved once, when claimed.)

A write that fails for want of space (``ENOSPC``, a quota, or a library's own words for
it, such as HDF5's "NetCDF: HDF error" on a full disk) raises :class:`OutputError`
saying "no space left" and naming the folder; the earlier outputs stay as they were.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import functools
import inspect
import json
import logging
import os
import re
import shutil
import socket
import stat
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path
from typing import Callable, Iterable, Iterator

from .._runtime.signals import interrupts_deferred
from ..errors import OutputError, SimlidarError, SimlidarWarning

log = logging.getLogger(__name__)

LOCK_NAME = ".simlidar-mi.lock"
#: The extended attribute that marks a file or folder as an output a run moved into place
#: (its size and modification time then, as JSON): the record that lets a later run remove it.
OUTPUT_XATTR = "user.simlidar-mi.output"
_STAGE_RE = re.compile(r"\.partial-(\d+)-[^/]*")       # staged_dir's folders
_TMP_RE = re.compile(r"\..+\.(\d+)-[^./]*\.partial")  # atomic_file's temporary files
_claims: dict[Path, list] = {}  # resolved folder -> [lock fd, depth, created]: reentrant per process
_claims_lock = threading.Lock()


# --- checking and claiming a folder ------------------------------------------------------


def _check_named(where: str | Path, what: str) -> None:
    """An empty name (``Path("")`` is ``.``) would silently mean the current folder: refuse it."""
    if isinstance(where, (str, bytes)) and not where.strip():
        raise OutputError(f"the output {what} is given as {where!r}, which names nothing: give a path "
                          "('.' for the current folder)")


def check_output_dir(out_dir: str | Path) -> None:
    """Raise :class:`OutputError` unless ``out_dir`` is a writable folder or can be made one."""
    _check_named(out_dir, "folder")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise OutputError(f"output folder {out} exists and is not a folder")
    probe = out
    while not probe.exists():  # nearest existing ancestor: it must be a writable folder
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"cannot make output folder {out}: {probe} is a file, not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputError(f"output folder {out} is not writable" if probe == out else
                          f"cannot make output folder {out}: {probe} is not writable")


def check_output_file(path: str | Path) -> None:
    """Raise :class:`OutputError` unless ``path`` can be written as a file."""
    _check_named(path, "file")
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"output file {path} is a folder")
    check_output_dir(path.parent)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # exists, another user's
    return True


def read_nofollow(path: str | Path, limit: int | None = 1 << 16) -> bytes:
    """The first ``limit`` bytes (None: all) of the regular file ``path``, its last component
    never followed as a link (OSError when it is one, or not a regular file)."""
    fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise OSError(errno.EINVAL, "not a regular file", str(path))
        if limit is not None:
            return os.read(fd, limit)
        with os.fdopen(os.dup(fd), "rb") as fh:
            return fh.read()
    finally:
        os.close(fd)


def refuse_linked_dir(folder: str | Path, what: str) -> None:
    """Refuse (OutputError) a ``folder`` that is a link or not a folder: ``what`` is written into
    it, and through a link it would land in (and replace files of) a folder elsewhere."""
    try:
        st = os.lstat(folder)
    except FileNotFoundError:
        return
    if not stat.S_ISDIR(st.st_mode):
        kind = "a symbolic link" if stat.S_ISLNK(st.st_mode) else "not a folder"
        raise OutputError(f"{folder} is {kind}: {what} and will not follow or replace it; remove it, "
                          "or use another output folder")


def _owner_text(lock_path: Path) -> str:
    try:
        info = json.loads(read_nofollow(lock_path).decode("utf-8"))
        return (f"process {info['pid']} on {info['host']} ({info['command']}, "
                f"since {info['started']})")
    except (OSError, ValueError, KeyError, TypeError):
        return "another process"


def _stale_owner(fd: int) -> int | None:
    """The pid a held lock file names when that process is gone from this host, else None."""
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode("utf-8"))
        pid, host = int(info["pid"]), info["host"]
    except (OSError, ValueError, KeyError, TypeError):
        return None  # being written, or not ours: in use
    return pid if host == socket.gethostname() and pid > 0 and not _alive(pid) else None


def _take_over(out: Path, path: Path, fd: int) -> bool:
    """Remove the lock file ``fd`` opened when the process it names is gone (its lock is kept
    by a process that inherited it), so that the next open makes a new one; whether it did.
    Under an flock of the folder itself, so two runs cannot both take over (the second would
    remove the first's new file)."""
    try:
        dir_fd = os.open(out, os.O_RDONLY | os.O_DIRECTORY)
    except OSError:
        return False
    try:
        fcntl.flock(dir_fd, fcntl.LOCK_EX)
        pid = _stale_owner(fd)
        try:
            same = pid is not None and os.fstat(fd).st_ino == os.lstat(path).st_ino
        except FileNotFoundError:
            return True  # its holder removed it meanwhile: try again
        if not same:
            return False
        path.unlink()
    finally:
        os.close(dir_fd)  # releases the folder's flock
    warnings.warn(SimlidarWarning(f"took over the lock of output folder {out}: the process it "
                                  f"names, {pid}, is gone (another that inherited the lock held it)"))
    return True


def _open_lock_file(out: Path, path: Path) -> int:
    """Open (or make) the lock file without following a link; refuse one that is a link, not
    a regular file, or a hard link to another name (writing it would change that file)."""
    try:  # O_NONBLOCK: a FIFO planted at the name must not hang the open
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, 0o644)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise OutputError(f"lock file {path} is a symbolic link: refusing to follow it (it is not "
                              "this program's); remove it, or use another output folder") from None
        if exc.errno in (errno.EISDIR, errno.ENXIO):
            raise OutputError(f"lock file {path} is not a regular file: remove it, or use another "
                              "output folder") from None
        raise OutputError(f"output folder {out} is not writable ({exc.strerror})") from exc
    st = os.fstat(fd)
    why = ("is not a regular file" if not stat.S_ISREG(st.st_mode) else
           f"has {st.st_nlink} hard links (another name shares it)" if st.st_nlink != 1 else None)
    if why is not None:
        os.close(fd)
        raise OutputError(f"lock file {path} {why}: refusing to write it; remove it, or use "
                          "another output folder")
    return fd


def _take_lock(out: Path) -> int:
    """flock ``out/LOCK_NAME`` for this process; its fd.  Refuses when another holds it,
    unless the process the lock names is gone (:func:`_take_over`)."""
    path = out / LOCK_NAME
    while True:
        fd = _open_lock_file(out, path)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EAGAIN, errno.EACCES):
                os.close(fd)
                raise OutputError(f"cannot lock output folder {out} ({exc.strerror})") from exc
            taken = _take_over(out, path, fd)
            os.close(fd)
            if taken:
                continue
            raise OutputError(f"output folder {out} is in use by {_owner_text(path)}; wait for "
                              f"it to finish or use another folder (lock file {path})") from None
        try:  # the holder before us may have removed the file as we opened it: retry
            same = os.fstat(fd).st_ino == os.lstat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    info = {"pid": os.getpid(), "host": socket.gethostname(),
            "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])[:300] if sys.argv else "python",
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    os.ftruncate(fd, 0)
    os.write(fd, (json.dumps(info) + "\n").encode())
    return fd


#: Below this many bytes free, a failed write is taken for a full disk whatever its words
#: (HDF5's "NetCDF: HDF error"); the failed run's own staged files are still there to count.
NEARLY_FULL_BYTES = 1 << 20


def _free_bytes(folder: Path) -> int | None:
    try:
        st = os.statvfs(folder)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize


def _no_space(exc: BaseException, out: Path) -> OutputError | None:
    """The one-line error for ``exc`` when it comes of a full disk or quota, else None."""
    if not isinstance(exc, Exception) or isinstance(exc, OutputError):
        return None
    chain, cause = [], exc
    while cause is not None and len(chain) < 20:
        chain.append(cause)
        cause = cause.__cause__ or cause.__context__
    full = any(isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EDQUOT) for e in chain)
    if not full:  # an I/O failure in a library's words (RuntimeError for HDF5) on a nearly full disk
        io = not isinstance(exc, SimlidarError) and any(isinstance(e, (OSError, RuntimeError)) for e in chain)
        free = _free_bytes(out) if io else None
        if free is None or free >= NEARLY_FULL_BYTES:
            return None
    words = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    return OutputError(f"no space left on the device of output folder {out} ({words}); the earlier "
                       "outputs there are unchanged: free some space or choose another folder")


@contextlib.contextmanager
def _space_errors(out: Path) -> Iterator[None]:
    try:
        yield
    except Exception as exc:
        err = _no_space(exc, out)
        if err is None:
            raise
        raise err from exc


def forget_claims_after_fork() -> None:
    """In a forked child: close the inherited lock files without unlocking them (the
    parent's own descriptors keep its locks), so the locks end with the parent."""
    for held in _claims.values():  # not under _claims_lock: another thread may have held it at fork
        with contextlib.suppress(OSError):
            os.close(held[0])
    _claims.clear()


def clean_stale_partials(out_dir: str | Path) -> list[Path]:
    """Remove staging folders and temporary files of dead runs in ``out_dir`` (and its
    sub-folders one level down); returns what was removed.  Only names carrying a pid
    (``.partial-<pid>-*``, ``.<name>.<pid>-*.partial``) whose process is gone."""
    out = Path(out_dir)
    removed = []
    folders = [out] + [p for p in out.iterdir() if p.is_dir() and not p.is_symlink()
                       and not _STAGE_RE.fullmatch(p.name)]
    for folder in folders:
        try:
            entries = list(folder.iterdir())
        except OSError:  # an unreadable sub-folder is not ours
            continue
        for p in entries:
            m = _STAGE_RE.fullmatch(p.name) or _TMP_RE.fullmatch(p.name)
            if m is None or _alive(int(m.group(1))):
                continue
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                with contextlib.suppress(FileNotFoundError):
                    p.unlink()
            removed.append(p)
            log.warning("removed %s, left by a run that was killed (process %s)", p, m.group(1))
    return removed


@contextlib.contextmanager
def claim_output(out_dir: str | Path) -> Iterator[Path]:
    """Check, lock and tidy ``out_dir`` for this run (see the module docstring).

    Reentrant within a process (a run calling another run, or :func:`staged_dir`, on the
    same folder).  On exit the lock file goes; a folder this claim created is removed
    again if it is still empty."""
    _check_named(out_dir, "folder")
    out = Path(out_dir)
    check_output_dir(out)
    key = out.resolve()
    with _claims_lock:
        held = _claims.get(key)
        if held is not None:
            held[1] += 1
        else:
            created = False
            try:
                out.parent.mkdir(parents=True, exist_ok=True)
                os.mkdir(out)  # not exist_ok: a name that appeared meanwhile is not taken for ours
                created = True
            except FileExistsError:
                if not out.is_dir():
                    raise OutputError(f"output folder {out} exists and is not a folder") from None
            except OSError as exc:
                raise OutputError(f"cannot make output folder {out} ({exc.strerror})") from exc
            try:
                fd = _take_lock(out)
            except BaseException:
                if created:
                    with contextlib.suppress(OSError):
                        out.rmdir()
                raise
            _claims[key] = held = [fd, 1, created]
    try:
        with _space_errors(out):
            if held[1] == 1:
                clean_stale_partials(out)
            yield out
    finally:
        with _claims_lock:
            held[1] -= 1
            if held[1] == 0:
                del _claims[key]
                with contextlib.suppress(OSError):  # while still locked: see _take_lock's retry
                    if os.lstat(out / LOCK_NAME).st_ino == os.fstat(held[0]).st_ino:  # ours, not a swapped name
                        (out / LOCK_NAME).unlink()
                os.close(held[0])
                if held[2]:
                    with contextlib.suppress(OSError):
                        out.rmdir()  # only if empty: a run that failed before writing


def writes_output(arg: str = "out_dir", *, file: bool = False) -> Callable:
    """Decorator: claim the folder given as argument ``arg`` for the whole call.

    The check comes before any work, so a bad output location fails at once rather than
    after the scan.  ``arg`` may be None (nothing written: no claim).  With ``file=True``
    the argument is one output file: only checked (its folder must be writable)."""
    def deco(fn: Callable) -> Callable:
        sig = inspect.signature(fn)

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            target = sig.bind(*args, **kwargs).arguments.get(arg, sig.parameters[arg].default)
            if target is None or target is inspect.Parameter.empty:
                return fn(*args, **kwargs)
            if file:
                check_output_file(target)
                return fn(*args, **kwargs)
            with claim_output(target):
                return fn(*args, **kwargs)
        return wrapper
    return deco


# --- staged writing ----------------------------------------------------------------------


def _owned(name: str, owns: Iterable[str]) -> bool:
    return not name.startswith(".") and any(re.fullmatch(p, name) for p in owns)


@contextlib.contextmanager
def staged_dir(out_dir: str | Path, owns: Iterable[str] = ()) -> Iterator[Path]:
    """Yield a staging folder; on success move its files into ``out_dir``.

    ``owns``: regular expressions (whole names) of the files and folders this run's kind
    writes in ``out_dir``; those it did not write this time are removed (and logged) when an
    earlier run recorded them as its outputs (:data:`OUTPUT_XATTR`), else left with a note.
    A sub-folder replaces the earlier output folder of its name as a whole; a folder of that
    name that no run recorded is refused (:class:`OutputError`), never removed."""
    owns = tuple(owns)
    with claim_output(out_dir) as claimed:
        out = claimed.resolve()  # once: a link swapped during the run does not move the files
        try:
            stage = Path(tempfile.mkdtemp(prefix=f".partial-{os.getpid()}-", dir=out))
        except OSError as exc:
            raise _no_space(exc, out) or exc
        try:
            with _space_errors(out):  # while the staged files still fill the disk
                yield stage
            with interrupts_deferred():  # Ctrl-C or SIGTERM here would leave half old, half new files
                _commit(stage, out, owns)
        finally:
            shutil.rmtree(stage, ignore_errors=True)


def _identity(st: os.stat_result) -> dict | None:
    """What :data:`OUTPUT_XATTR` records of a file or folder (None: neither, e.g. a link)."""
    kind = "file" if stat.S_ISREG(st.st_mode) else "folder" if stat.S_ISDIR(st.st_mode) else None
    return None if kind is None else {"kind": kind, "size": st.st_size, "mtime_ns": st.st_mtime_ns}


def _record_output(path: Path) -> None:
    """Mark ``path`` (a staged output, about to be moved into place: a rename keeps its size,
    time and attributes) as this program's output.  A file system without user extended
    attributes records nothing: a later run then leaves the file rather than remove it."""
    try:
        ident = _identity(os.lstat(path))
        if ident is not None:
            os.setxattr(path, OUTPUT_XATTR, json.dumps(ident, sort_keys=True).encode(),
                        follow_symlinks=False)
    except OSError as exc:
        log.debug("cannot record %s as an output (%s): a later run will leave it", path, exc.strerror)


def recorded_output(path: str | Path) -> bool:
    """Whether ``path`` is an output an earlier run moved into place, unchanged since: its
    :data:`OUTPUT_XATTR` record matches its kind, size and modification time (a link, a
    user's file of the same name or one rewritten since: False)."""
    try:
        st = os.lstat(path)
        rec = json.loads(os.getxattr(path, OUTPUT_XATTR, follow_symlinks=False))
    except (OSError, ValueError):
        return False
    ident = _identity(st)
    return ident is not None and rec == ident


def _commit(stage: Path, out: Path, owns: tuple[str, ...]) -> None:
    items = sorted(stage.iterdir())
    for item in items:  # first, before anything moves: a folder in the way that is not ours
        dest = out / item.name
        if dest.is_dir() and not dest.is_symlink() and not recorded_output(dest):
            raise OutputError(f"output folder {out} holds a folder {item.name!r} that no earlier run "
                              "wrote: move it away (it is not removed), or use another output folder")
    written = set()
    for item in items:
        dest = out / item.name
        if dest.is_dir() and not dest.is_symlink():  # os.replace cannot replace a folder
            os.replace(dest, stage / f".old-{item.name}")
        _record_output(item)
        os.replace(item, dest)  # over a link at that name: the link goes, nothing is written through it
        written.add(item.name)
    for p in sorted(out.iterdir()):
        if p.name in written or not _owned(p.name, owns):
            continue
        if not recorded_output(p):
            log.warning("left %s: an output name of this run that it does not write, but no earlier run "
                        "recorded it as its output (another program's, or changed since)", p)
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        else:
            p.unlink()
        log.warning("removed %s: an earlier run's output that this run does not write", p)


@contextlib.contextmanager
def atomic_file(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it to ``path`` on success.

    The temporary name carries the pid (``.<name>.<pid>-*.partial``), so that a claimed
    folder's next run can tell one left by a killed process.  It is made with ``O_EXCL``
    (never through a link) and renamed over ``path`` (a link there is replaced, not followed)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}-", suffix=".partial",
                               dir=path.parent)
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.fchmod(fd, 0o666 & ~umask)  # mkstemp makes 0600; outputs are ordinary files (by fd: no name lookup)
    finally:
        os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)


def write_csv(path: str | Path, fieldnames, rows, *, extrasaction: str = "raise") -> Path:
    """Write dict ``rows`` as UTF-8 CSV with a header, atomically; returns the path."""
    import csv  # noqa: PLC0415

    with atomic_file(path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            w = csv.DictWriter(fh, fieldnames=list(fieldnames), extrasaction=extrasaction)
            w.writeheader()
            w.writerows(rows)
    return Path(path)
