"""A held scan's files (EXR, PNG per leg; one LAS) and its measures, the LAS in a child process.

The writers are independent once the scan is done.  The LAS file is the longest of them
(0.7 s of a fresh 7×4 Table 3 scan, as long as the EXR, the PNG and the measures together),
so on a POSIX system it is written by a forked child process while this process writes the
rest: the child sees the scan's arrays as they are (copy-on-write, nothing is sent), and the
two run on both cores.  Threads were measured first and bought nothing: the LAS and the
measures are many short numpy calls, and each waits for the GIL that the other holds
(BENCHMARKS.md §8e).

Every file goes through :func:`simlidar_mi.io.atomic.atomic_file` inside the run's staged
folder, so a failure leaves nothing half-written: this process always waits for the child,
then raises the first error (the LAS writer's, as a :class:`~simlidar_mi.errors.SimlidarError`
with its message, else its own), and the staged folder is discarded by its owner
(:func:`simlidar_mi.io.atomic.staged_dir`).  The bytes of each file do not depend on where
it was written.
"""
from __future__ import annotations

import os
import sys
import traceback
from pathlib import Path
from typing import Callable

from ..errors import SimlidarError

#: Write the LAS file in a forked child process (POSIX only); False: here, in turn.
FORK_LAS = hasattr(os, "fork")


class _Child:
    """A forked process running one call; :meth:`wait` returns once it has ended."""

    def __init__(self, name: str, call: Callable[[], object]):
        self.name = name
        for stream in (sys.stdout, sys.stderr):  # nothing buffered is written twice
            stream.flush()
        read, write = os.pipe()
        self.pid = os.fork()
        if self.pid == 0:  # the child: run, report, and end without the parent's teardown
            code = 1
            try:
                os.close(read)
                call()
                code = 0
            except BaseException as exc:  # noqa: BLE001 - every failure goes to the parent
                text = "".join(traceback.format_exception_only(type(exc), exc)).strip()
                os.write(write, text.encode("utf-8", "replace")[:8192])
            finally:
                os._exit(code)
        os.close(write)
        self.read = read

    def wait(self) -> None:
        """Wait for the child; raise SimlidarError with its message if it failed."""
        try:
            with os.fdopen(self.read, "rb") as pipe:
                message = pipe.read().decode("utf-8", "replace")
        finally:  # reaped even when interrupted while reading
            _, status = os.waitpid(self.pid, 0)
        code = os.waitstatus_to_exitcode(status)
        if code != 0:
            raise SimlidarError(f"writing {self.name} failed: {message or f'exit status {code}'}")


def write_held_scan(results: list, stage: Path, out_dir: Path, *, exr_kwargs: dict,
                    png_titles: list[str] | None, las: bool, crs: str | None,
                    also: Callable[[], object] | None = None) -> tuple[dict[str, Path], object]:
    """Write ``results`` (one ScanResult per leg, held in memory) into ``stage``.

    scan.exr / scan.png (one leg) or scan_legJ.exr / scan_legJ.png, and points.las with
    every leg's points (``las``); ``png_titles`` None writes no PNG.  ``also``: one more
    call made here while the LAS is written (the run's measures).  Returns ({key: final
    path in ``out_dir``} in the order the files were always listed: each leg's EXR and
    PNG, then the LAS; what ``also`` returned, else None)."""
    from ..io.exr import write_scan_exr  # noqa: PLC0415
    many = len(results) > 1
    files: dict[str, Path] = {}
    child = None
    if las:
        from ..io.las import write_scan_las  # noqa: PLC0415

        def las_job():
            write_scan_las(results if many else results[0], stage / "points.las", crs=crs)
        if FORK_LAS:
            child = _Child("points.las", las_job)
    try:
        done = also() if also is not None else None
        for j, res in enumerate(results):
            stem, tag = ("scan", "") if not many else (f"scan_leg{j}", str(j))
            write_scan_exr(res, stage / f"{stem}.exr", **exr_kwargs)
            files[f"exr{tag}"] = out_dir / f"{stem}.exr"
            if png_titles is not None:
                from ..io.plots import plot_scan_png  # noqa: PLC0415
                plot_scan_png(res, stage / f"{stem}.png", title=png_titles[j])
                files[f"png{tag}"] = out_dir / f"{stem}.png"
        if las and child is None:
            las_job()
    finally:  # the child has ended before anything here is raised or the stage removed
        if child is not None:
            child.wait()
    if las:
        files["las"] = out_dir / "points.las"
    return files, done
