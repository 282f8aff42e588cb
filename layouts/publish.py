"""Output folders written whole or not at all, and never over an input: the one place outputs are published.

A command builds its outputs in a staging folder (`stage`) on OUT's own filesystem, then `publish` swaps
them in:

* OUT missing: the stage is ``.OUT.partial-PID`` beside OUT (OUT will live on its parent's filesystem)
  and is renamed to OUT in one step.
* OUT present: the stage is ``OUT/.partial-PID``, inside OUT, so it is on OUT's filesystem even when OUT
  is a mount point; each entry is swapped in with `os.replace`, an earlier output of the same name first
  moved aside into ``OUT/.partial-PID-old``. Should any move fail, every move done is undone, so OUT holds
  its earlier outputs whole; the old ones are deleted only once every new one is in.

`check_writable` probes OUT (or the folder it will be made in) before any work, so a read-only or
missing place is one line, not a traceback after the work; a write that fails later, while the outputs
are being staged (a full disk, a quota, a filesystem turned read-only), is one line too (`write_failed`),
the stage removed and OUT as it was. `refuse_overlap` refuses an output that is,
lies inside or holds an input. Stale stages of processes no longer alive are removed when the next
stage is made.

`lock` holds OUT for one command at a time (a second writer into the same OUT is one line, not a race
the last one wins); `staged` is the whole path in one block: stage, write, publish, or on failure
discard and say it in one line. `output_folder` is the one way a command writes its output folder: the rules on
OUT (`refuse_overlap`, `check_out`: missing, empty or an earlier output of the same command unless
``overwrite``), then `staged`. A command that resumes into OUT (`generate`, `merge-shards`) writes in place
under `lock` after the same checks; `map` writes its passes into OUT in place while its stage fills
(``make``).
"""

from __future__ import annotations

import errno
import os
import re
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager, nullcontext
from pathlib import Path

from layouts.errors import InputError

#: names of staging entries inside OUT: ``.partial-PID`` (the new outputs), ``.partial-PID-old`` (the old)
STAGE_RE = re.compile(r"^\.partial-(\d+)(-old)?$")


def is_stage_name(name: str) -> bool:
    """Whether an entry of OUT is a staging folder (`stage`), not an output."""
    return STAGE_RE.match(name) is not None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True  # e.g. another user's process
    return True


def _stale(pid: str) -> bool:
    return pid.isdigit() and int(pid) != os.getpid() and not _alive(int(pid))


def _cannot(what: str, out: Path, e: OSError, tail: str = "") -> InputError:
    reason = e.strerror or type(e).__name__
    return InputError(f"{what} {out}: cannot write there ({reason}){tail}")


def _existing_ancestor(path: Path) -> Path:
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def check_writable(out: str | os.PathLike, what: str = "--out") -> None:
    """One line unless OUT can be written: OUT itself when it exists (a folder), else the nearest folder it
    would be made in. Probed by making and removing an empty folder, so it asks the filesystem itself
    (a read-only mount, permissions, quotas on folders), not the permission bits."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{what} {out}: exists and is not a folder")
    where = out if out.is_dir() else _existing_ancestor(out.parent)
    if not where.is_dir():
        raise InputError(f"{what} {out}: {where} is not a folder")
    try:
        probe = tempfile.mkdtemp(prefix=".partial-probe-", dir=where)
        os.rmdir(probe)
    except OSError as e:
        raise _cannot(what, out, e) from None


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        try:
            path.unlink()
        except FileNotFoundError:
            pass


def stage(out: str | os.PathLike, what: str = "--out") -> Path:
    """A fresh, empty staging folder on OUT's filesystem (see the module docstring); stale ones of
    processes no longer alive are removed. One line when it cannot be made."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{what} {out}: exists and is not a folder")
    try:
        if out.is_dir():
            for old in out.iterdir():
                m = STAGE_RE.match(old.name)
                if m and _stale(m.group(1)):
                    _remove(old)
            st = out / f".partial-{os.getpid()}"
        else:
            out.parent.mkdir(parents=True, exist_ok=True)
            prefix = f".{out.name}.partial-"
            for old in out.parent.glob(f"{prefix}*"):
                if _stale(old.name[len(prefix) :]) and old.is_dir():
                    shutil.rmtree(old, ignore_errors=True)
            st = out.parent / f"{prefix}{os.getpid()}"
        if st.exists():
            shutil.rmtree(st)
        st.mkdir()
    except OSError as e:
        raise _cannot(what, out, e) from None
    return st


def publish(
    st: str | os.PathLike, out: str | os.PathLike, managed: Iterable[str] | None = None, what: str = "--out"
) -> None:
    """Move everything staged in ``st`` (made by `stage`) into OUT.

    ``managed``: the output names this command owns; one of them this run did not make is removed (it
    would be stale), nothing else in OUT is touched. None: every entry of OUT is the command's (an export
    folder): OUT ends up holding exactly the staged entries. On failure OUT keeps its earlier outputs
    whole and the stage is removed; the error is one line."""
    st, out = Path(st), Path(out)
    if out.exists() and not out.is_dir():
        shutil.rmtree(st, ignore_errors=True)
        raise InputError(f"{what} {out}: exists and is not a folder")
    if st.parent != out:  # staged beside a missing OUT: one rename
        try:
            os.replace(st, out)
            return
        except OSError as e:
            if not out.is_dir():
                shutil.rmtree(st, ignore_errors=True)
                raise _cannot(what, out, e) from None
            # OUT was made meanwhile: swap entry by entry below, from a stage inside it
            inner = stage(out, what)
            for item in st.iterdir():
                shutil.move(str(item), str(inner / item.name))
            st.rmdir()
            st = inner
    made = sorted(p.name for p in st.iterdir())
    old_names = [p.name for p in out.iterdir() if not is_stage_name(p.name)] if managed is None else list(managed)
    aside = out / f"{st.name}-old"
    done: list[tuple[Path, Path]] = []  # (from, to) of every move made, to undo them
    try:
        aside.mkdir(exist_ok=True)
        for name in sorted(set(old_names) | set(made)):
            dst = out / name
            if dst.exists() or dst.is_symlink():
                os.replace(dst, aside / name)
                done.append((dst, aside / name))
            if name in made:
                os.replace(st / name, dst)
                done.append((st / name, dst))
    except BaseException as e:  # a failed move, or Ctrl-C / SIGTERM between two: undo every move made
        kept = ""
        for src, dst in reversed(done):
            try:
                os.replace(dst, src)
            except OSError:
                kept = f"; the earlier outputs are in {aside}"
        shutil.rmtree(st, ignore_errors=True)
        if not kept:
            shutil.rmtree(aside, ignore_errors=True)
        if not isinstance(e, OSError):
            raise
        raise _cannot(what, out, e, kept or "; the earlier outputs are kept") from None
    shutil.rmtree(aside, ignore_errors=True)
    shutil.rmtree(st, ignore_errors=True)


#: errors of a write whatever the file: no room, over a quota, too large, the filesystem read-only
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS})


def is_write_failure(e: BaseException, where: str | os.PathLike) -> bool:
    """Whether ``e`` is a failed write into the folder ``where``: an `OSError` about a file under it, or one
    that only a write gives (`WRITE_ERRNOS`). A missing or unreadable input is not."""
    if not isinstance(e, OSError):
        return False
    if e.errno in WRITE_ERRNOS:
        return True
    if e.filename is None or not isinstance(e.filename, (str, os.PathLike)):
        return False
    path, folder = Path(os.path.abspath(e.filename)), Path(os.path.abspath(where))
    return path == folder or folder in path.parents


def write_failed(e: OSError, out: str | os.PathLike, what: str = "--out", tail: str = "") -> InputError:
    """The one line for a write that failed while a command's outputs were staged (`is_write_failure`),
    ``--out OUT: cannot write there (No space left on device); the earlier outputs are kept``, with the file
    and the room left when known (``No space left on device: warehouse.rrd, 327680 bytes free``); the caller
    removes its stage, so that OUT keeps them whole. ``tail``: other words on what is kept."""
    if isinstance(e.filename, (str, os.PathLike)) and e.strerror:
        name = Path(e.filename).name
        free = ""
        if e.errno in (errno.ENOSPC, errno.EDQUOT):
            try:
                free = f", {shutil.disk_usage(_existing_ancestor(Path(e.filename))).free} bytes free"
            except OSError:
                pass
        e = OSError(e.errno, f"{e.strerror}: {name}{free}")
    return _cannot(what, Path(out), e, tail or "; the earlier outputs are kept")


def discard(st: str | os.PathLike) -> None:
    """Remove a stage after a failed or interrupted command (OUT stays as it was)."""
    shutil.rmtree(st, ignore_errors=True)


def _busy(what: str, out: Path) -> InputError:
    return InputError(f"{what} {out}: another command is writing there now; wait for it to end or give another {what}")


def _take(target: Path, out: Path, what: str) -> int:
    """An open descriptor of ``target`` (OUT itself, or the lock file beside a missing OUT) holding its lock."""
    import fcntl

    try:
        if target == out:
            fd = os.open(target, os.O_RDONLY | os.O_DIRECTORY)
        else:
            target.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(target, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as e:
        raise _cannot(what, out, e) from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise _busy(what, out) from None
    except OSError:
        pass  # no locks on this filesystem
    try:
        held = os.path.samestat(os.fstat(fd), os.stat(target))
    except OSError:
        held = False
    if not held:  # the lock file removed (or OUT replaced) meanwhile by the command that held it
        os.close(fd)
        raise _busy(what, out)
    return fd


@contextmanager
def lock(out: str | os.PathLike, what: str = "--out", make: bool = False) -> Iterator[None]:
    """OUT held by this command for the block: a second command writing into the same OUT meanwhile is refused
    in one line (both would stage, and the last to publish would win). An existing OUT is locked itself
    (``flock`` on the folder); a missing one through ``.OUT.lock`` beside it, removed at the end. ``make``: a
    missing OUT is made (under the lock beside it) and locked itself, for a command that writes into OUT before it
    publishes (`map`'s passes); removed again at the end while still empty. Filesystems without locks (some
    network mounts) go unlocked."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{what} {out}: exists and is not a folder")
    made = False
    if make and not out.is_dir():
        with lock(out, what):
            try:
                out.mkdir(parents=True)
            except FileExistsError:
                raise _busy(what, out) from None
            except OSError as e:
                raise _cannot(what, out, e) from None
            made = True
            try:
                fd = _take(out, out, what)
            except BaseException:
                out.rmdir()
                raise
    target = out if out.is_dir() else out.parent / f".{out.name}.lock"
    if not made:
        fd = _take(target, out, what)
    try:
        yield
    finally:
        if target != out:
            try:
                target.unlink()
            except OSError:
                pass
        if made:
            try:
                out.rmdir()  # only when empty: the command left nothing there
            except OSError:
                pass
        os.close(fd)  # the lock goes with the descriptor


@contextmanager
def staged(
    out: str | os.PathLike,
    managed: Iterable[str] | None = None,
    what: str = "--out",
    locked: bool = True,
    make: bool = False,
) -> Iterator[Path]:
    """The one way an output folder is written: OUT held (`lock`, unless the caller holds it: ``locked`` False;
    ``make``: OUT made first, as `lock` does), a stage made (`stage`) and yielded to be filled, then published
    (`publish`, ``managed`` as there). When the block fails, the stage is removed and OUT is as it was; a failed
    write into the stage (a full disk) is one line (`write_failed`)."""
    out = Path(out)
    with lock(out, what, make) if locked else nullcontext():
        st = stage(out, what)
        try:
            yield st
        except BaseException as e:
            discard(st)
            if is_write_failure(e, st):
                raise write_failed(e, out, what) from None
            raise
        publish(st, out, managed, what)


def _overlap(a: Path, b: Path) -> bool:
    return a == b or a in b.parents or b in a.parents


def _real(p: str | os.PathLike) -> Path:
    return Path(os.path.realpath(os.path.abspath(os.fspath(p))))


def refuse_overlap(
    outputs: Iterable[str | os.PathLike],
    inputs: Mapping[str, str | os.PathLike | None],
    what: str = "--out",
) -> None:
    """One line when an output path is, lies inside or holds an input path (links resolved).

    ``outputs``: the paths a command writes (``OUT/layouts``, ``OUT/warehouse.json``; OUT itself for a
    command that owns all of OUT), so an OUT may hold an input it leaves alone. ``inputs``: what the user
    calls each input (``INPUT``, ``--camera``) -> its path (None: not given, skipped)."""
    for opath in outputs:
        o = _real(opath)
        for iname, ipath in inputs.items():
            if ipath is None:
                continue
            i = _real(ipath)
            if _overlap(o, i):
                rel = "is" if o == i else ("lies inside" if i in o.parents else "holds")
                raise InputError(f"{what} {opath}: {rel} the input {iname} {ipath}; write the outputs elsewhere")


def check_out(
    out: str | os.PathLike,
    overwrite: bool,
    outputs: Iterable[str] | None,
    earlier: Callable[[Path], bool],
    command: str,
    untouched: Iterable[str] = (),
    what: str = "--out",
) -> None:
    """Refuse an OUT that is neither missing, empty nor an earlier output folder of ``command`` (only ``outputs`` in
    it, ``earlier(OUT)`` true; ``outputs`` None: the command owns every entry of OUT), unless ``overwrite``: then
    only the command's outputs are replaced. ``untouched``: outputs the command leaves alone (reconstruct's
    layouts/); alone in OUT they count as empty. Probes that OUT can be written (`check_writable`)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{what} {out}: exists and is not a folder")
    check_writable(out, what)
    if overwrite or not out.is_dir():
        return
    names = {p.name for p in out.iterdir() if not is_stage_name(p.name)}
    if names <= set(untouched):
        return
    own = names if outputs is None else set(outputs) | set(untouched)
    if names <= own and earlier(out):
        return  # an earlier output folder of the command
    other = sorted(names - own)
    held = f"holds other files ({', '.join(other[:3])}{', ...' if len(other) > 3 else ''})" if other else None
    if outputs is None:
        held, tail = held or "holds other files", "replace everything there"
    else:
        tail = "replace the outputs there (nothing else is touched)"
    raise InputError(
        f"{what} {out}: {held or 'has no map'}, not an earlier {command}'s output folder; give --overwrite to {tail} "
        f"or another {what}"
    )


@contextmanager
def output_folder(
    out: str | os.PathLike,
    outputs: Iterable[str] | None,
    *,
    command: str,
    earlier: Callable[[Path], bool],
    inputs: Mapping[str, str | os.PathLike | None] | None = None,
    overwrite: bool = False,
    untouched: Iterable[str] = (),
    may_hold_inputs: bool = False,
    what: str = "--out",
    make: bool = False,
) -> Iterator[Path]:
    """The one way a command writes its output folder OUT: refused in one line when an output would be, lie
    inside or hold one of ``inputs`` (`refuse_overlap`; those not on disk skipped) or when OUT is not missing,
    empty or an earlier output of ``command`` unless ``overwrite`` (`check_out`); then OUT held, a stage yielded
    to be filled and swapped in whole (`staged`), or on failure OUT left as it was.

    ``outputs``: the names the command writes in OUT (None: all of OUT is the command's, an export);
    ``earlier(OUT)``: whether a folder holding only those is the command's own earlier output; ``may_hold_inputs``:
    OUT may hold an input the command leaves alone (reconstruct's OUT/layouts), only the outputs are checked;
    ``make``: OUT is made and held before the block, for a command that also writes into OUT in place while the stage
    fills (`map`'s passes, one of its ``untouched``: kept by the publishing)."""
    out = Path(out)
    given = {k: v for k, v in (inputs or {}).items() if v is not None and Path(v).exists()}
    refuse_overlap([out / n for n in outputs] if may_hold_inputs and outputs else [out], given, what)
    outputs = None if outputs is None else tuple(outputs)
    check_out(out, overwrite, outputs, earlier, command, untouched, what)
    with staged(out, outputs, what, make=make) as st:
        yield st
