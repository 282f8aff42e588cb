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
import re
from collections.abc import Callable, Hashable, Iterable, Iterator
from functools import partial
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


def connect(address: str, num_cpus: int | None = None) -> None:
    """Connect this process to the Ray cluster at ``address`` (`check_ray_address`), once: ``local`` starts one of
    ``num_cpus`` CPUs here. Already connected: kept as it is. A cluster not found is one line."""
    address = check_ray_address(address, "--ray")
    ray = import_ray()
    if ray.is_initialized():
        return
    if address.startswith("ray://") and importlib.util.find_spec("grpc") is None:
        raise InputError(f"--ray {address}: Ray Client needs its extra: pip install 'ray[client]'")
    quiet = {"include_dashboard": False, "logging_level": "ERROR", "configure_logging": True}
    try:
        if address == "local":
            # Ray starts a local cluster with token authentication on and makes a token itself when there is none
            # (~/.ray/auth_token; no network); the notice that it did so is left out of the output.
            logging.getLogger("ray._private.authentication.authentication_token_setup").setLevel(logging.ERROR)
            ray.init(num_cpus=num_cpus, **quiet)
        elif address.startswith("ray://"):
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
