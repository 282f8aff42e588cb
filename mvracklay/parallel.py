"""Where the libraries' work runs: this process, local worker processes, or Ray tasks on a cluster.

The libraries are plain functions on data; a command fans their work out through this one module::

    from mvracklay.parallel import run_tasks

    for key, result in run_tasks(fn, [(key, argument), ...], workers=4, ray=None, progress="map"):
        ...  # each (key, fn(argument)) as it completes, in the order the tasks finish

* ``fn``: a module-level function of one argument (it and the arguments are pickled to the workers; on a
  cluster every node imports ``fn``'s module, so the same environment must be installed there).
* ``items``: ``(key, argument)`` pairs; the key (a sequence or pass name) comes back with the result.
* ``ray=None``: ``workers`` 1 runs the items one after another in this process; more runs them in that many
  local processes (`layouts.tasks.process_map`: started from a clean forkserver, stopped by joining).
* ``ray=ADDRESS``: each item is one Ray task holding ``cpus_per_task`` CPUs, as many at once as the cluster
  has room for. ADDRESS is ``auto`` (the cluster this machine belongs to, as ``ray start`` made it), ``HOST:PORT``
  (a cluster's head node), ``ray://HOST:PORT`` (Ray Client; needs ``pip install 'ray[client]'``) or ``local``
  (start a Ray of ``workers`` CPUs on this machine for this process). A process that is already connected to
  Ray (``ray.init`` called before, as the tests do) keeps its connection. Ray is imported only here and only
  when asked; where it is not installed, the error says how to install it.
* ``progress``: a progress bar of finished items with this description (None: none).
* ``retries``: how often Ray runs a task again whose worker or node was lost (default 3, as Ray's).

Connecting is bounded in time: a cluster that does not answer within `connect_timeout` seconds (30, or
``MVRACKLAY_RAY_TIMEOUT``) is one line naming the address given, never a retry loop: the host is resolved and
its port reached first, each under the deadline, and only then is Ray asked to connect, its own retries held
to the time left.

Errors: the first task that raises ends the run and its exception is raised from the iteration as itself
(an `InputError` stays one, and the CLI prints it as one line; from Ray with a note naming the task and its
traceback there); the tasks not yet started are cancelled. A task Ray could not run (a worker or node lost, out of memory) is `TaskFailed`, one
line. A bad ADDRESS or a cluster that cannot be reached is an `InputError`.

`task_map` gives the same as a `layouts.tasks.TaskMap`, the argument by which a library (``waresynth``'s
dataset writers) takes where to run its work.
"""

from __future__ import annotations

import importlib.util
import logging
import multiprocessing as mp
import os
import re
import socket
import tempfile
import threading
import time
from collections.abc import Callable, Hashable, Iterable, Iterator
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from layouts.errors import InputError

if TYPE_CHECKING:
    from layouts.tasks import TaskMap

#: what ``--ray`` says in every command's help
RAY_HELP = (
    "run the work as Ray tasks: 'auto' (the Ray cluster this machine belongs to), HOST:PORT (a cluster's head), "
    "ray://HOST:PORT (Ray Client) or 'local' (start a Ray of --workers CPUs here); the output folder must be on a "
    "filesystem every node sees at the same path (docs/distributed.md)"
)
INSTALL = "pip install 'mvracklay[ray]' (or 'ray>=2.60')"
_HOST_PORT = re.compile(r"^(ray://)?[A-Za-z0-9_.\-\[\]:]+:(\d{1,5})$")
#: seconds a connection to a Ray cluster may take, unless ``MVRACKLAY_RAY_TIMEOUT`` says otherwise
CONNECT_TIMEOUT_S = 30.0
TIMEOUT_ENV = "MVRACKLAY_RAY_TIMEOUT"


class TaskFailed(RuntimeError):
    """A task the cluster could not run to its end (its worker or node lost, out of memory): one line."""


def check_ray_address(address: Any, name: str = "--ray") -> str:
    """``address`` if it is one `run_tasks` takes (``auto``, ``local``, ``HOST:PORT``, ``ray://HOST:PORT``), else
    a one-line `InputError` naming ``name``."""
    if not isinstance(address, str) or not address.strip():
        raise InputError(f"{name} must be auto, local, HOST:PORT or ray://HOST:PORT, got {address!r}")
    address = address.strip()
    if address in ("auto", "local"):
        return address
    m = _HOST_PORT.match(address)
    if m is None or not 0 < int(m.group(2)) < 65536:
        raise InputError(f"{name} must be auto, local, HOST:PORT or ray://HOST:PORT, got {address!r}")
    return address


def run_tasks(
    fn: Callable[[Any], Any],
    items: Iterable[tuple[Hashable, Any]],
    *,
    workers: int = 1,
    ray: str | None = None,
    cpus_per_task: float = 1,
    progress: str | None = None,
    mp_context: mp.context.BaseContext | None = None,
    retries: int = 3,
) -> Iterator[tuple[Hashable, Any]]:
    """``(key, fn(argument))`` for each ``(key, argument)`` of ``items``, as each completes (the module's
    docstring says where they run and how errors come back). ``mp_context``: how local workers start (default:
    a forkserver that imported ``fn``'s module); ``retries``: how often Ray runs a task again whose worker or
    node was lost (the task must then be safe to run twice, as a sequence written under a temporary name is)."""
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= 1024:
        raise InputError(f"workers must be an integer in [1, 1024], got {workers!r}")
    if isinstance(cpus_per_task, bool) or not isinstance(cpus_per_task, (int, float)) or not cpus_per_task > 0:
        raise InputError(f"cpus_per_task must be a number > 0, got {cpus_per_task!r}")
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise InputError(f"retries must be an integer >= 0, got {retries!r}")
    if not callable(fn):
        raise InputError(f"fn must be a function, got {type(fn).__name__}")
    if ray is not None:
        ray = check_ray_address(ray, "ray")
    items = list(items)
    if not all(isinstance(it, tuple) and len(it) == 2 for it in items):
        raise InputError("items must be (key, argument) pairs")
    if ray is not None:
        if items:
            connect(ray, workers)  # a cluster not found: one line now, not at the first result
        results = _ray_map(fn, items, cpus_per_task, retries)
    elif workers == 1 or len(items) <= 1:
        results = ((key, fn(arg)) for key, arg in items)
    else:
        from layouts.tasks import process_map

        results = process_map(fn, items, workers, mp_context or _clean_context(fn))
    return results if not progress else _counted(results, len(items), progress)


def _counted(results: Iterator[tuple[Hashable, Any]], total: int, desc: str) -> Iterator[tuple[Hashable, Any]]:
    """``results`` passed through, a progress bar counting them."""
    from tqdm import tqdm

    with tqdm(total=total, unit="task", desc=desc, dynamic_ncols=True) as bar:
        for pair in results:
            bar.update(1)
            yield pair


def task_map(*, workers: int = 1, ray: str | None = None, cpus_per_task: float = 1) -> TaskMap:
    """`run_tasks` with these settings as a `layouts.tasks.TaskMap` (``tasks(fn, items)``), for a library's
    ``tasks`` argument (e.g. `waresynth.generate.generate_dataset`)."""
    if ray is not None:
        check_ray_address(ray, "ray")
    return partial(run_tasks, workers=workers, ray=ray, cpus_per_task=cpus_per_task)


def _clean_context(fn: Callable[[Any], Any]) -> mp.context.BaseContext:
    """Workers forked from a forkserver that imported ``fn``'s module (no threads of this process inherited)."""
    if "forkserver" in mp.get_all_start_methods():
        ctx = mp.get_context("forkserver")
        module = getattr(fn, "__module__", None)
        if module and module != "__main__":
            ctx.set_forkserver_preload([module])
        return ctx
    return mp.get_context("spawn")


# ----------------------------------------------------------------------------- Ray
def import_ray() -> Any:
    """The ``ray`` module, or a one-line `InputError` saying how to install it."""
    try:
        import ray
    except ImportError:
        raise InputError(f"--ray needs Ray, which is not installed: {INSTALL}") from None
    return ray


def connect_timeout() -> float:
    """Seconds a connection to a Ray cluster may take: ``MVRACKLAY_RAY_TIMEOUT`` when set, else `CONNECT_TIMEOUT_S`."""
    text = os.environ.get(TIMEOUT_ENV, "").strip()
    if not text:
        return CONNECT_TIMEOUT_S
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 < value <= 3600:
        raise InputError(f"{TIMEOUT_ENV} must be a number of seconds in (0, 3600], got {text!r}")
    return value


def connect(address: str, num_cpus: int | None = None, timeout_s: float | None = None) -> None:
    """Connect this process to the Ray cluster at ``address`` (`check_ray_address`), once: ``local`` starts one of
    ``num_cpus`` CPUs here. Already connected: kept as it is. A cluster not found, or not answering within
    ``timeout_s`` seconds (default `connect_timeout`), is one line naming ``address``."""
    address = check_ray_address(address, "--ray")
    timeout_s = connect_timeout() if timeout_s is None else float(timeout_s)
    ray = import_ray()
    if ray.is_initialized():
        return
    if address.startswith("ray://") and importlib.util.find_spec("grpc") is None:
        raise InputError(f"--ray {address}: Ray Client needs its extra: pip install 'ray[client]'")
    deadline = time.monotonic() + timeout_s
    target = _auto_address() if address == "auto" else address
    if target not in ("auto", "local") and _HOST_PORT.match(target):
        reach(target, timeout_s, f"--ray {address}")
    quiet = {"include_dashboard": False, "logging_level": "ERROR", "configure_logging": True}
    try:
        if address == "local":
            # Ray starts a local cluster with token authentication on and makes a token itself when there is none
            # (~/.ray/auth_token; no network): made here first, readable by its owner only (`private_token`); the
            # notice that Ray turned authentication on is left out of the output.
            private_token()
            logging.getLogger("ray._private.authentication.authentication_token_setup").setLevel(logging.ERROR)
            ray.init(num_cpus=num_cpus, **quiet)
        else:
            # Ray retries a cluster that does not answer about once a second for this many tries (read at each call)
            left = max(1, int(deadline - time.monotonic()))
            with _environ(RAY_gcs_server_port_wait_time_s=str(left)):
                if address.startswith("ray://"):
                    ray.init(address=address, logging_level="ERROR")
                else:
                    ray.init(address=address, **quiet)
    except (ConnectionError, TimeoutError, RuntimeError, ValueError) as e:
        first = (str(e).strip().splitlines() or [type(e).__name__])[0]
        hint = (
            " (start one with `ray start --head`, or pass --ray local)"
            if address == "auto"
            else " (a cluster with token authentication also needs RAY_AUTH_MODE=token and its token here)"
        )
        raise InputError(f"--ray {address}: cannot connect to a Ray cluster{hint}: {first}") from None


def _auto_address() -> str:
    """Where ``--ray auto`` connects: ``RAY_ADDRESS``, else the cluster ``ray start`` last started here (its address
    file); "" when neither says."""
    given = os.environ.get("RAY_ADDRESS", "").strip()
    if given:
        return given
    try:
        from ray._private.utils import read_ray_address

        return (read_ray_address() or "").strip()
    except Exception:  # noqa: BLE001 - another Ray's layout: Ray finds the address itself
        return ""


def reach(address: str, timeout_s: float, name: str = "--ray") -> None:
    """Check that something answers at ``address`` (``HOST:PORT`` or ``ray://HOST:PORT``) within ``timeout_s``
    seconds, the host name resolved and a TCP connection opened, each under the deadline; else one `InputError`
    line naming ``name`` and the address as given (Ray itself would retry for minutes, naming another address)."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    host = host.strip("[]")
    deadline = time.monotonic() + timeout_s
    said = f"{name}: no Ray cluster answered within {timeout_s:g} s"
    found: list = []
    problem: list[str] = []

    def resolve() -> None:
        try:
            found.extend(socket.getaddrinfo(host, int(port), type=socket.SOCK_STREAM))
        except (OSError, UnicodeError) as e:
            problem.append(f"host {host} not found: {e.strerror or e}" if isinstance(e, OSError) else str(e))

    looking = threading.Thread(target=resolve, name="ray-resolve", daemon=True)  # getaddrinfo has no timeout
    looking.start()
    looking.join(timeout_s)
    if looking.is_alive():
        raise InputError(f"{said} (resolving host {host} did not finish)")
    if not found:
        raise InputError(f"{said} ({problem[0] if problem else f'host {host} not found'})")
    why = "timed out"
    for family, kind, proto, _, sockaddr in found:
        left = deadline - time.monotonic()
        if left <= 0:
            break
        try:
            with socket.socket(family, kind, proto) as s:
                s.settimeout(left)
                s.connect(sockaddr)
                if os.environ.get("RAY_USE_TLS", "0").strip().lower() in ("0", "false", ""):
                    s.settimeout(max(0.01, deadline - time.monotonic()))
                    if not _speaks_grpc(s):
                        why = "the port answers, but not as a Ray cluster's (gRPC) does"
                        continue
            return
        except TimeoutError:
            why = "timed out"
        except OSError as e:
            why = (e.strerror or type(e).__name__).lower()
    raise InputError(f"{said} ({why})")


def _speaks_grpc(s: socket.socket) -> bool:
    """Whether the server on ``s`` answers as a gRPC server (a Ray head's GCS, a Ray Client server) does: HTTP/2,
    whose first frame is its SETTINGS, sent in reply to the client's preface (before any authentication)."""
    s.sendall(b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0]))  # preface, SETTINGS
    head = b""
    while len(head) < 9:
        part = s.recv(9 - len(head))
        if not part:
            return False
        head += part
    return head[3] == 4 and not head[4] & 1  # a SETTINGS frame, not an acknowledgement


@contextmanager
def _environ(**values: str) -> Iterator[None]:
    """Environment variables set for the duration of a ``with`` block (any the user set are kept as they are)."""
    values = {k: v for k, v in values.items() if k not in os.environ}
    os.environ.update(values)
    try:
        yield
    finally:
        for k in values:
            os.environ.pop(k, None)


def private_token() -> Path | None:
    """The token file a local Ray reads (``~/.ray/auth_token``), readable by its owner only: made here (a random
    token, the way Ray makes one; the folder 0700, the file 0600, written whole) when Ray would make it itself,
    with the permissions of any file, and an existing one readable by others narrowed to 0600. None when the
    token comes from elsewhere (``RAY_AUTH_TOKEN``, ``RAY_AUTH_TOKEN_PATH``), authentication is off
    (``RAY_AUTH_MODE=disabled``) or there is no home folder."""
    if os.environ.get("RAY_AUTH_TOKEN") or os.environ.get("RAY_AUTH_TOKEN_PATH"):
        return None
    if os.environ.get("RAY_AUTH_MODE", "").strip().lower() == "disabled":
        return None
    try:
        path = Path.home() / ".ray" / "auth_token"
    except RuntimeError:
        return None
    try:
        if path.is_file():
            if path.stat().st_mode & 0o077:
                path.chmod(0o600)
            return path
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        import secrets

        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".auth_token.", suffix=".tmp")  # made 0600
        try:
            with os.fdopen(fd, "w") as f:
                f.write(secrets.token_hex(32))
                f.flush()
                os.fsync(f.fileno())
            os.link(tmp, path)  # never over a token another process has just made
        except FileExistsError:
            pass
        finally:
            os.unlink(tmp)
    except OSError as e:
        raise InputError(f"--ray local: cannot make Ray's token file {path} ({e.strerror or e})") from None
    return path


def shutdown() -> None:
    """Disconnect this process from Ray (stopping a cluster `connect` started with ``local``); no-op otherwise."""
    if importlib.util.find_spec("ray") is None:
        return
    import ray

    if ray.is_initialized():
        ray.shutdown()


def _ray_map(
    fn: Callable[[Any], Any], items: list[tuple[Hashable, Any]], cpus: float, retries: int
) -> Iterator[tuple[Hashable, Any]]:
    """``(key, result)`` of one Ray task per item on the connected cluster, as each completes (`run_tasks`)."""
    if not items:
        return
    ray = import_ray()
    remote = ray.remote(num_cpus=cpus, max_retries=retries)(fn)
    pending = {remote.remote(arg): key for key, arg in items}
    try:
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                key = pending.pop(ref)
                yield key, _ray_result(ray, ref, key)
    except BaseException:
        for ref in pending:
            ray.cancel(ref)
        raise


def _ray_result(ray: Any, ref: Any, key: Hashable) -> Any:
    """The result of one finished task, or its error: the task's own exception, or `TaskFailed` (one line)."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as e:
        cause = e.cause
        if isinstance(cause, Exception) and not isinstance(cause, ray.exceptions.RayError):
            there = re.sub(r"\x1b\[[0-9;]*m", "", getattr(e, "traceback_str", None) or str(e))  # no colour codes
            cause.add_note(f"(in Ray task {key!r}; its traceback there:)\n{there.rstrip()}")
            raise cause from None
        raise TaskFailed(f"task {key!r} failed on the Ray cluster: {_first_line(cause or e)}") from None
    except ray.exceptions.RayError as e:
        raise TaskFailed(f"task {key!r} could not finish on the Ray cluster: {_first_line(e)}") from None


def _first_line(e: BaseException) -> str:
    lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
    return f"{type(e).__name__}: {lines[0] if lines else ''}".rstrip(": ")
