"""A held scan's files (EXR, PNG per leg; one LAS) written side by side (issue #8).

The writers are independent once the scan is done, and most of their time is spent where
Python lets other threads run: zlib (EXR blocks, Pillow's PNG encoder), numpy on the LAS
columns and the file writes.  So they run on a small thread pool, and the CPU of a 2-core
machine is shared between them instead of one writer waiting for the other
(BENCHMARKS.md §8e measures what it buys).

Every writer goes through :func:`simlidar_mi.io.atomic.atomic_file` inside the run's
staged folder, so a failure leaves nothing half-written: the first error (in the order
the files are listed) is raised once every writer has stopped, and the staged folder is
then discarded by its owner (:func:`simlidar_mi.io.atomic.staged_dir`).  Each file's
bytes do not depend on the threads: every writer works on its own arrays and file.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable

#: Threads for the writers (the EXR writer compresses on 2 threads of its own): 2 measured
#: best on the 2-core machine, 3 no better (BENCHMARKS.md §8e).
WRITER_THREADS = 2


def run_side_by_side(jobs: list[tuple[str, Callable[[], object]]],
                     threads: int | None = None) -> dict[str, object]:
    """Run ``jobs`` ((name, call) pairs) on ``threads`` threads (default
    :data:`WRITER_THREADS`, read at the call); return {name: result}.

    Waits for every job, then raises the first failure in job order (one clear error,
    raised once no writer is still running).  With one job or ``threads`` ≤ 1 the calls
    run here, in order."""
    threads = WRITER_THREADS if threads is None else threads
    if threads <= 1 or len(jobs) <= 1:
        return {name: call() for name, call in jobs}
    with ThreadPoolExecutor(min(threads, len(jobs)), thread_name_prefix="simlidar-writer") as pool:
        futures = [(name, pool.submit(call)) for name, call in jobs]
        try:
            errors = [f.exception() for _, f in futures]  # waits for each
        except BaseException:  # e.g. Ctrl-C while waiting: start no queued job
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    for error in errors:
        if error is not None:
            raise error
    return {name: f.result() for name, f in futures}


def write_held_scan(results: list, stage: Path, out_dir: Path, *, exr_kwargs: dict,
                    png_titles: list[str] | None, las: bool, crs: str | None,
                    also: Callable[[], object] | None = None) -> tuple[dict[str, Path], object]:
    """Write ``results`` (one ScanResult per leg, held in memory) into ``stage``.

    scan.exr / scan.png (one leg) or scan_legJ.exr / scan_legJ.png, and points.las with
    every leg's points (``las``); ``png_titles`` None writes no PNG.  ``also``: one more
    job run beside the writers (the run's measures).  Returns ({key: final path in
    ``out_dir``} in the order the files were always listed: each leg's EXR and PNG, then
    the LAS; what ``also`` returned, else None)."""
    from ..io.exr import write_scan_exr  # noqa: PLC0415
    if png_titles is not None:
        from ..io.plots import plot_scan_png  # noqa: PLC0415
    many = len(results) > 1
    files: dict[str, Path] = {}
    jobs: list[tuple[str, Callable[[], object]]] = []
    if las:  # the longest writer first, so it is never the one left running alone
        from ..io.las import write_scan_las  # noqa: PLC0415
        jobs.append(("las", lambda: write_scan_las(results if many else results[0],
                                                   stage / "points.las", crs=crs)))
    if also is not None:
        jobs.append(("also", also))
    for j, res in enumerate(results):
        stem, tag = ("scan", "") if not many else (f"scan_leg{j}", str(j))
        jobs.append((f"exr{tag}", lambda res=res, stem=stem: write_scan_exr(res, stage / f"{stem}.exr", **exr_kwargs)))
        files[f"exr{tag}"] = out_dir / f"{stem}.exr"
        if png_titles is not None:
            jobs.append((f"png{tag}", lambda res=res, stem=stem, title=png_titles[j]:
                         plot_scan_png(res, stage / f"{stem}.png", title=title)))
            files[f"png{tag}"] = out_dir / f"{stem}.png"
    if las:
        files["las"] = out_dir / "points.las"
    done = run_side_by_side(jobs)
    return files, done.get("also")
