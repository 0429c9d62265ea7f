"""Progress of long commands: a tqdm bar on a terminal, one line per stage when piped.

The one progress helper of the package (scan, preview, gapfraction, synthetic-photo,
forest, compare, photo-gap use it).  Every API function that takes ``progress=``
accepts what :func:`make_progress` does:

- ``False`` / ``None`` (the library default): silent;
- ``True``: a tqdm bar on stderr when stderr is a terminal, else one summary line per
  finished stage on stderr (``stage: 16 replicates in 12.9 s``), so logs of piped or
  background runs show where time went without carriage-return clutter; a stage of
  minutes (``ticks=True``: the study's orchards) adds a line per item or per 5 %;
- ``"bar"`` / ``"lines"``: that mode regardless of the terminal; a :class:`Progress`.

Stdout is never written: it holds the commands' results (JSON, tables).  A stage that
fails prints no summary line, so the error line is the last one.
"""
from __future__ import annotations

import os
import sys
import time
from typing import IO, Any, Iterable, Iterator

from ..errors import ConfigError

MODES = ("off", "bar", "lines")


class Stage:
    """One stage of work: counts items (``update``) or named steps (``step``).

    Use as a context manager, or call :meth:`close`; a stage given a ``total`` of
    steps closes itself after the last :meth:`step`.
    """

    def __init__(self, owner: "Progress", desc: str, total: int | None, unit: str,
                 delay_s: float = 0.0, ticks: bool = False) -> None:
        self.owner, self.desc, self.total, self.unit = owner, desc, total, unit
        self.ticks = ticks and bool(total)  # piped: a line per item (per 5 % of more than 20)
        self.n = 0
        self.note = ""
        self.t0 = self._t_step = time.perf_counter()
        self._stepped = self._closed = False
        self._bar = None
        if owner.mode == "bar":
            from tqdm import tqdm  # noqa: PLC0415  (only on a terminal)
            # a terminal that reports a 0 × 0 size (a bare pty) would get no bar at all
            sized = _columns(owner.stream) > 0
            self._bar = tqdm(total=total, desc=desc, unit=unit, leave=False, file=owner.stream,
                             dynamic_ncols=sized, ncols=None if sized else 80,
                             nrows=None if sized else 24, delay=delay_s)

    def update(self, n: int = 1, note: str | None = None) -> None:
        """``n`` more items done; ``note`` is shown beside the bar and in the summary."""
        self.n += n
        if note is not None:
            self.note = note
        if self._bar is not None:
            if note is not None:
                self._bar.set_postfix_str(note, refresh=False)
            self._bar.update(n)
        elif self.ticks and self.owner.mode == "lines":
            step = 1 if self.total <= 20 else self.total / 20
            if int(self.n / step) > int((self.n - n) / step) or self.n >= self.total:
                unit = self.unit if self.total == 1 else _plural(self.unit)
                self.owner.line(f"{self.desc}: {self.n}/{self.total} {unit} done "
                                f"({100 * self.n / self.total:.0f} %, {time.perf_counter() - self.t0:.1f} s)")

    def step(self, note: str) -> None:
        """A named step finished (``generated 4912 branches``): one line when piped."""
        self.n += 1
        self._stepped = True
        now = time.perf_counter()
        if self._bar is not None:
            self._bar.set_description(note, refresh=False)
            self._bar.update(1)
        elif self.owner.mode == "lines":
            self.owner.line(f"{self.desc}: {note} ({now - self._t_step:.1f} s)")
        self._t_step = now
        if self.total is not None and self.n >= self.total:
            self.close()

    def close(self, ok: bool = True) -> None:
        """End the stage; when piped and ``ok``, print its one-line summary."""
        if self._closed:
            return
        self._closed = True
        if self._bar is not None:
            self._bar.close()
        if ok and self.owner.mode == "lines" and not self._stepped:
            count = f"{self.n}/{self.total}" if self.total not in (None, self.n) else f"{self.n}"
            unit = self.unit if self.n == 1 else _plural(self.unit)
            note = f", {self.note}" if self.note else ""
            self.owner.line(f"{self.desc}: {count} {unit}{note} "
                            f"({time.perf_counter() - self.t0:.1f} s)")

    def __enter__(self) -> "Stage":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(ok=exc_type is None)


class Progress:
    """Where and how progress is shown: ``mode`` is one of :data:`MODES`."""

    def __init__(self, mode: str = "off", stream: IO[str] | None = None) -> None:
        if mode not in MODES:
            raise ConfigError(f"valid: {', '.join(MODES)}", key="progress", value=mode)
        self.mode = mode
        self.stream = stream if stream is not None else sys.stderr

    @property
    def enabled(self) -> bool:
        return self.mode != "off"

    def stage(self, desc: str, total: int | None = None, unit: str = "step",
              delay_s: float = 0.0, ticks: bool = False) -> Stage:
        """A stage; on a terminal its bar appears only after ``delay_s`` (short work stays quiet).
        ``ticks``: when piped, also one line per finished item (per 5 % of more than 20 items),
        for stages of minutes (``study``), not only the summary at the end."""
        return Stage(self, desc, total, unit, delay_s, ticks)

    def iter(self, items: Iterable, desc: str, total: int | None = None,
             unit: str = "item") -> Iterator:
        """``items`` one by one, counted in a stage (its summary only when all were consumed)."""
        if total is None and hasattr(items, "__len__"):
            total = len(items)  # type: ignore[arg-type]
        st = self.stage(desc, total, unit)
        done = False
        try:
            for x in items:
                yield x
                st.update()
            done = True
        finally:
            st.close(ok=done)

    def line(self, text: str) -> None:
        """A progress line: printed unless silent (above the bars on a terminal)."""
        if self.enabled:
            self.write(text)

    def write(self, text: str) -> None:
        """A line on the progress stream (stderr) in any mode, e.g. an error that does not
        stop the command; on a terminal it goes above the bars instead of through them."""
        if self.mode == "bar":
            from tqdm import tqdm  # noqa: PLC0415
            tqdm.write(text, file=self.stream)
        else:
            print(text, file=self.stream, flush=True)


def make_progress(progress: Any = False, stream: IO[str] | None = None) -> Progress:
    """A :class:`Progress` from an API function's ``progress=`` argument (see the module doc)."""
    if isinstance(progress, Progress):
        return progress
    if progress is None or progress is False or progress == "off":
        return Progress("off", stream)
    if progress is True or progress == "auto":
        s = stream if stream is not None else sys.stderr
        tty = bool(getattr(s, "isatty", lambda: False)())
        return Progress("bar" if tty else "lines", stream)
    if progress in ("bar", "lines"):
        return Progress(progress, stream)
    raise ConfigError("must be True, False, 'auto', 'bar', 'lines' or a Progress",
                      key="progress", value=progress)


def bar(items: Iterable, progress: Any, desc: str, total: int | None = None,
        unit: str = "item") -> Iterable:
    """``items`` counted as one stage of ``make_progress(progress)``; ``items`` itself when silent."""
    p = make_progress(progress)
    return p.iter(items, desc, total, unit) if p.enabled else items


def _columns(stream: IO[str]) -> int:
    try:
        return os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, OSError, ValueError):
        return 0


def _plural(unit: str) -> str:
    if unit.endswith(("s", "sh", "ch", "x")):
        return unit + "es"
    return unit + "s"
