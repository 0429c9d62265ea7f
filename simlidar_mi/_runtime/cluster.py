"""Where a sweep's tasks run: the local process pool, or a Dask ``distributed`` cluster.

Shared by every sweep (today :func:`simlidar_mi.lidar.study.run_study`) and by scans split
into row tiles (:mod:`simlidar_mi.lidar.tiles`, from ``run_scan``).  A sweep asks
:func:`cluster_client` which cluster to use, in this order:

1. ``scheduler`` given (``--scheduler ADDRESS``): that scheduler; ``"local"`` forces the
   local process pool even when one of the next two is set;
2. an active :class:`distributed.Client` in this process (``distributed.default_client()``,
   e.g. one a notebook made with ``Client("tcp://...")``), used and left open;
3. ``DASK_SCHEDULER_ADDRESS`` in the environment (or Dask's ``scheduler-address`` config);
4. none: the sweep runs on the local process pool as it always did.

``distributed`` is imported only when one of 1–3 applies, so local runs pay nothing.

Connecting takes at most ``CONNECT_TIMEOUT_S`` (30 s; ``SIMLIDAR_MI_DASK_TIMEOUT_S`` in the
environment sets another) plus a few seconds' grace: a server on that port that never answers
as a scheduler would (an HTTP server), an address nothing listens on, or a ``tls://`` address
without Dask's TLS settings each end in one :class:`ConfigError` line; so does an empty
address (``--scheduler ""``), which never means "local".
"""
from __future__ import annotations

import contextlib
import functools
import hashlib
import logging
import os
import math
import socket
import sys
import threading
from pathlib import Path
from typing import Any, Callable, Iterator

from .._version import __version__
from ..errors import ConfigError

log = logging.getLogger(__name__)

LOCAL = "local"
ENV = "DASK_SCHEDULER_ADDRESS"
CONNECT_TIMEOUT_S = 30  # a cluster's scheduler may be slow to answer, but not forever
TIMEOUT_ENV = "SIMLIDAR_MI_DASK_TIMEOUT_S"
GRACE_S = 5.0  # beyond the timeout, for distributed to give up on its own and say why
_failed: list = []  # errors of failed connections, kept: freeing a half-made Client prints a traceback


def _active_client():
    """The process's default ``distributed`` Client, or None (without importing distributed
    when nothing could have made one)."""
    if "distributed" not in sys.modules:
        return None
    from distributed import default_client  # noqa: PLC0415
    try:
        client = default_client()
    except ValueError:  # "No clients found"
        return None
    return client if client.status == "running" else None


def check_scheduler(scheduler: Any) -> str | None:
    """``scheduler`` stripped (None: not given); a :class:`ConfigError` unless it is None or a
    non-empty string (an empty one is a mistake, not "local")."""
    if scheduler is None:
        return None
    if not isinstance(scheduler, str):
        raise ConfigError("must be a scheduler address such as 'tcp://host:8786', or 'local'",
                          key="scheduler", value=scheduler)
    if not scheduler.strip():
        raise ConfigError("is empty: give a scheduler address such as 'tcp://host:8786', or 'local' "
                          "for this machine's processes", key="scheduler", value=scheduler)
    return scheduler.strip()


def connect_timeout_s() -> float:
    """Seconds to wait for a scheduler: ``SIMLIDAR_MI_DASK_TIMEOUT_S``, else CONNECT_TIMEOUT_S."""
    text = os.environ.get(TIMEOUT_ENV, "").strip()
    if not text:
        return float(CONNECT_TIMEOUT_S)
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ConfigError("must be a number of seconds > 0", key=TIMEOUT_ENV, value=text)
    return value


def may_use_cluster(scheduler: str | None = None) -> bool:
    """Whether :func:`cluster_client` would hand out a Client for ``scheduler`` (without
    connecting): an address, else an active Client or a configured address."""
    scheduler = check_scheduler(scheduler)
    if scheduler:
        return scheduler != LOCAL
    return _active_client() is not None or configured_address() is not None


def configured_address() -> str | None:
    """``DASK_SCHEDULER_ADDRESS``, else Dask's ``scheduler-address`` config, else None."""
    address = os.environ.get(ENV, "").strip()
    if address:
        return address
    if not _dask_config_may_exist():  # spares every local run the ~0.1 s import of dask
        return None
    import dask  # noqa: PLC0415
    return dask.config.get("scheduler-address", None) or None


def _dask_config_dirs() -> list[Path]:
    """The folders Dask reads YAML config from (``dask.config.paths``, listed without
    importing dask): ``DASK_ROOT_CONFIG`` or /etc/dask, <prefix>/etc/dask, ~/.config/dask."""
    import site  # noqa: PLC0415
    prefixes = [sys.prefix, *getattr(site, "PREFIXES", [])]
    return [Path("/etc/dask"), *(Path(p) / "etc" / "dask" for p in prefixes),
            Path.home() / ".config" / "dask"]


def _dask_config_may_exist() -> bool:
    """Whether Dask's config could name a scheduler: dask already imported (a config set in
    this process), a ``DASK_*`` environment variable (values, ``DASK_CONFIG``,
    ``DASK_ROOT_CONFIG``), or a file in one of Dask's config folders."""
    if "dask" in sys.modules or any(k.startswith("DASK_") for k in os.environ):
        return True
    return any(d.is_dir() and any(d.iterdir()) for d in _dask_config_dirs())


@contextlib.contextmanager
def cluster_client(scheduler: str | None = None) -> Iterator[Any]:
    """The ``distributed.Client`` a sweep should submit to, or None for the local pool.

    A Client this function connects is closed on exit; an active one is left open."""
    scheduler = check_scheduler(scheduler)
    if scheduler == LOCAL:
        yield None
        return
    if scheduler is None:
        active = _active_client()
        if active is not None:
            yield active
            return
        scheduler = configured_address()
        if scheduler is None:
            yield None
            return
    client = _connect(scheduler, connect_timeout_s())
    try:
        yield client
    finally:
        client.close()


def _connect(address: str, timeout_s: float) -> Any:
    """A Client of the scheduler at ``address``, or a one-line :class:`ConfigError` within
    ``timeout_s`` + GRACE_S, whatever answers there (distributed's own timeout does not cover
    a server that accepts the connection and never answers)."""
    from distributed import Client, Security  # noqa: PLC0415
    from distributed.comm.addressing import parse_address  # noqa: PLC0415

    def error(why: str) -> ConfigError:
        return ConfigError(f"cannot reach the Dask scheduler ({why}); start one with 'dask scheduler', "
                           f"or leave --scheduler and {ENV} unset for the local process pool",
                           key="scheduler", value=address)
    try:
        scheme, _ = parse_address(address)
    except ValueError as exc:
        raise error(f"not an address: {exc}") from None
    why = _unusable_scheme(scheme, address)
    if why:
        raise error(why)
    if scheme == "tls" and Security().get_connection_args("client").get("ssl_context") is None:
        raise error("a tls:// address needs Dask's TLS settings: distributed.comm.tls.ca-file, "
                    ".client.cert and .client.key")
    outcome: dict[str, Any] = {}

    def connect() -> None:
        try:
            outcome["client"] = Client(address, timeout=timeout_s, set_as_default=False)
        except BaseException as exc:  # noqa: BLE001  (any failure is this one line's)
            _failed.append(exc)
            outcome["error"] = exc
    chatty = logging.getLogger("distributed")
    level = chatty.level
    chatty.setLevel(logging.CRITICAL)  # its retries and garbage frames ("Unable to allocate 3 EiB")
    try:
        thread = threading.Thread(target=connect, name="simlidar-dask-connect", daemon=True)
        thread.start()
        thread.join(timeout_s + GRACE_S)
    finally:
        chatty.setLevel(level)
    if "client" in outcome:
        return outcome["client"]
    if "error" in outcome:
        exc = outcome["error"]
        words = (str(exc).strip().splitlines() or [""])[0]
        raise error(f"{type(exc).__name__}: {words}" if words else type(exc).__name__)
    raise error(f"no answer as a Dask scheduler within {timeout_s:g} s; {TIMEOUT_ENV} sets the wait")


def _unusable_scheme(scheme: str, address: str) -> str | None:
    """Why ``address`` cannot name a scheduler we could reach, before distributed tries (its
    own errors for these are Python internals: an unpacking error, an abstract class)."""
    from distributed.comm.addressing import parse_address, parse_host_port  # noqa: PLC0415
    from distributed.comm.registry import get_backend  # noqa: PLC0415
    try:
        get_backend(scheme)
    except ValueError as exc:  # "unknown address scheme 'http' (known schemes: [...])"
        return str(exc)
    if scheme in ("tcp", "tls", "ws", "wss"):
        try:
            parse_host_port(parse_address(address)[1])
        except ValueError as exc:  # "missing port number in address 'garbage!!'"
            return f"not an address: {exc}"
    if scheme == "inproc":
        from distributed.comm.inproc import global_manager  # noqa: PLC0415
        try:
            listening = global_manager.get_listener_for(address.split("://", 1)[1]) is not None
        except ValueError:
            listening = False
        if not listening:
            return ("an inproc:// address names a scheduler inside this same Python process, and none "
                    "listens there; give the tcp:// address of a running scheduler")
    if scheme == "ucx":
        import importlib.util  # noqa: PLC0415
        if importlib.util.find_spec("distributed_ucxx") is None:
            return ("the ucx:// protocol needs the distributed-ucxx package (Distributed no longer "
                    "ships UCX), which is not installed; give a tcp:// address")
    return None


def worker_name() -> str:
    """Who runs this task: the Dask worker's address on a cluster, else
    ``local:<host>:<pid>`` (the local pool's process, or the study's own)."""
    if "distributed" in sys.modules:
        from distributed import get_worker  # noqa: PLC0415
        try:
            return get_worker().address
        except ValueError:  # not inside a distributed worker
            pass
    return f"{LOCAL}:{socket.gethostname()}:{os.getpid()}"


def run_on_client(client: Any, fn: Callable, calls: list[tuple], on_result: Callable[[Any], None],
                  shared: Any = None) -> None:
    """``fn(shared, *args)`` for each ``args`` of ``calls`` on the cluster; ``on_result`` gets
    each result in this process as soon as its task finishes (so a Ctrl-C or a failed task
    leaves every result already handed over saved).  ``shared`` is sent to the cluster once.
    The first failed task raises its error here; the tasks not yet finished are cancelled."""
    from distributed import as_completed  # noqa: PLC0415
    if not client.scheduler_info().get("workers"):
        log.warning("the Dask scheduler %s has no workers yet: the tasks wait for one",
                    client.scheduler.address)
    [shared_f] = client.scatter([shared], hash=False)
    futures = [client.submit(fn, shared_f, *args, pure=False) for args in calls]
    try:
        for fut in as_completed(futures, loop=client.loop):
            on_result(fut.result())
    finally:
        pending = [f for f in futures if not f.done()]
        if pending:
            client.cancel(pending)
        client.cancel([shared_f])


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """``<version>+<source digest> mitsuba <v> drjit <v>``: the package version, a digest of
    the package's and its Mitsuba plugins' Python source (so an edited checkout counts as
    other code), and the Mitsuba and Dr.Jit that scan."""
    import importlib.metadata as md  # noqa: PLC0415
    import importlib.util  # noqa: PLC0415

    # Files are named as they sit in an installed wheel (plugins under simlidar_mi/plugins/),
    # so a cluster worker with the wheel agrees with a study run from a source checkout,
    # where plugins/ is a top-level folder.
    files: dict[str, Path] = {}
    package = Path(__file__).resolve().parent
    spec = importlib.util.find_spec("simlidar_mi.plugins")
    roots = [(package, "")] + [(Path(p).resolve(), "plugins/")
                               for p in ((spec.submodule_search_locations or []) if spec else [])]
    for root, prefix in roots:
        for f in root.rglob("*.py"):
            if "__pycache__" not in f.parts:
                files[prefix + f.relative_to(root).as_posix()] = f
    digest = hashlib.sha256()
    for name in sorted(files):
        digest.update(name.encode() + b"\0" + files[name].read_bytes() + b"\0")
    libs = []
    for dist in ("mitsuba", "drjit"):
        try:
            libs.append(f"{dist} {md.version(dist)}")
        except md.PackageNotFoundError:
            libs.append(f"{dist} ?")
    return " ".join([f"{__version__}+{digest.hexdigest()[:12]}", *libs])
