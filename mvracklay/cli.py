"""``mvracklay`` command line: finds the sub-commands in `mvracklay.commands` and runs one.

Each command module declares ``NAME``, ``HELP``, ``GROUP`` ("use", "data" or "models") and ``ORDER`` as
literals; they are read from the module's source (`ast`), so ``mvracklay --help`` imports no command
and ``mvracklay COMMAND ...`` imports that command's module only. A module may also define
``config_defaults(args, parser) -> dict`` (defaults from ``--quality`` / ``--config``, re-parsed under
the command line) and ``RESUME`` (what to say when the command is interrupted: how to resume it) or
``INTERRUPTED`` (what to say then of a command with nothing to resume). SIGTERM is handled like Ctrl-C:
raised as `Terminated` (a `KeyboardInterrupt`) in the main thread, so the command's clean-up runs; exit
status 130 after Ctrl-C, 143 after SIGTERM. A closed stdout (``| head``) ends the command quietly, status 141.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import os
import pkgutil
import signal
import sys
import textwrap
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from mvracklay import __version__, commands

#: the groups ``mvracklay --help`` lists the commands in, in order
GROUPS = {"use": "using it", "data": "data", "models": "models"}
#: the group of a command module that declares none
DEFAULT_GROUP = "models"
_LITERALS = ("NAME", "HELP", "GROUP", "ORDER")


@dataclass(frozen=True)
class CommandInfo:
    """What ``mvracklay --help`` says of a command, read without importing it."""

    module: str  #: e.g. ``mvracklay.commands.free_space``
    name: str  #: e.g. ``free-space``
    help: str
    group: str
    order: float


def _literals(path: Path) -> dict[str, object]:
    """The module-level literal assignments `_LITERALS` of the source file ``path``."""
    found: dict[str, object] = {}
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            key = node.targets[0].id
            if key in _LITERALS:
                try:
                    found[key] = ast.literal_eval(node.value)
                except ValueError:
                    pass  # not a literal: read from the imported module below
    return found


def command_infos() -> list[CommandInfo]:
    """Every command (modules of `mvracklay.commands` not starting with ``_``), by group and ``ORDER``."""
    infos = []
    for info in pkgutil.iter_modules(commands.__path__):
        if info.name.startswith("_"):
            continue
        module = f"mvracklay.commands.{info.name}"
        found = _literals(Path(commands.__path__[0]) / f"{info.name}.py")
        if "NAME" not in found or "HELP" not in found:  # computed: import the module for them
            mod = importlib.import_module(module)
            found = {k: getattr(mod, k) for k in _LITERALS if hasattr(mod, k)}
        group = str(found.get("GROUP", DEFAULT_GROUP))
        infos.append(
            CommandInfo(module, str(found["NAME"]), str(found["HELP"]), group, float(found.get("ORDER", 50)))  # type: ignore[arg-type]
        )
    rank = {g: i for i, g in enumerate(GROUPS)}
    return sorted(infos, key=lambda c: (rank.get(c.group, len(rank)), c.order, c.name))


def commands_epilog(infos: list[CommandInfo], width: int = 100) -> str:
    """The command listing of ``mvracklay --help``, one block per group."""
    lines = []
    pad = max(len(c.name) for c in infos) + 4
    for group in [*GROUPS, *sorted({c.group for c in infos} - set(GROUPS))]:
        members = [c for c in infos if c.group == group]
        if not members:
            continue
        lines.append(f"commands, {GROUPS.get(group, group)}:")
        for c in members:
            wrapped = textwrap.wrap(c.help, max(40, width - pad - 2)) or [""]
            lines.append(f"  {c.name:<{pad}}{wrapped[0]}")
            lines += [" " * (pad + 2) + w for w in wrapped[1:]]
        lines.append("")
    lines.append(
        "'mvracklay COMMAND --help' lists a command's options; docs/cli.md: the groups, presets, config files."
    )
    return "\n".join(lines)


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Defaults shown in the help, except an unset ``None`` and a switch's ``False`` (the help text says
    what happens then)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None or (action.default is False and action.nargs == 0):
            return action.help
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    """The whole parser: every command's options (imports every command module)."""
    return _build(None)[0]


def _build(only: str | None) -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser]]:
    """The parser and its sub-parsers by name; with ``only`` (a command name, or "" for none) the options
    of that command alone, the others stubs whose modules are not imported."""
    infos = command_infos()
    parser = argparse.ArgumentParser(
        prog="mvracklay",
        description=(
            "Warehouse rack layouts from monocular video: generate synthetic data, train and run the "
            "MVRackLay network, stitch per-frame layouts into a 3D map, query free shelf space."
        ),
        epilog=commands_epilog(infos),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"mvracklay {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", help="one of the commands listed below")
    subparsers = {}
    for info in infos:
        if only is not None and info.name != only:
            subparsers[info.name] = sub.add_parser(info.name)
            continue
        mod = importlib.import_module(info.module)
        p = sub.add_parser(info.name, description=getattr(mod, "DESCRIPTION", mod.HELP), formatter_class=HelpFormatter)
        if hasattr(mod, "add_arguments"):
            mod.add_arguments(p)
        else:  # a command whose options its settings dataclass makes
            from mvracklay.settings import add_options

            add_options(p, mod.SETTINGS)
        p.set_defaults(_module=info.module, _run=mod.run)
        subparsers[info.name] = p
    return parser, subparsers


def _command_of(argv: Sequence[str]) -> str:
    """The command named on a command line ("" for none): its first word not an option (the top level's
    options, -h and --version, take no value)."""
    return next((a for a in argv if not a.startswith("-")), "")


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the main thread runs so that clean-up (``finally``, staging folders) happens."""


def _on_sigterm(pid: int):
    def handler(signum: int, frame: object) -> None:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a second SIGTERM ends the process at once
        if os.getpid() != pid:  # a forked worker: die as it would have
            os.kill(os.getpid(), signal.SIGTERM)
            return
        raise Terminated

    return handler


def _close_progress_bars() -> None:
    """End the progress bars an interrupted command left open, so the message after them starts a line."""
    tqdm = sys.modules.get("tqdm")
    for bar in list(getattr(getattr(tqdm, "tqdm", None), "_instances", ())):
        bar.close()


#: exit status when the reader of stdout went away (``mvracklay run ... | head``): 128 + SIGPIPE, as a shell
#: reports a writer a closed pipe ended; nothing is printed and OUT holds whatever the command had published
BROKEN_PIPE = 141


def main(argv: Sequence[str] | None = None) -> int:
    from mvracklay.threads import quiet_openmp

    quiet_openmp()  # before any command imports torch: idle OpenMP threads sleep (mvracklay/threads.py)
    try:
        if threading.current_thread() is not threading.main_thread():
            return _flushed(_main(argv))
        previous = signal.signal(signal.SIGTERM, _on_sigterm(os.getpid()))
        try:
            return _flushed(_main(argv))
        finally:
            signal.signal(signal.SIGTERM, previous)
    except BrokenPipeError:
        _quiet_stdout()
        return BROKEN_PIPE


def _flushed(rc: int) -> int:
    """``rc`` once stdout is flushed (so a closed pipe shows here, not as a message at exit)."""
    sys.stdout.flush()
    return rc


def _quiet_stdout() -> None:
    """Point stdout at /dev/null: the interpreter's last flush then has nowhere to fail."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # no file descriptor (a captured stdout in tests)
        pass


def _main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    name = _command_of(argv)
    parser, subparsers = _build(only=name)
    args = parser.parse_args(argv)
    if not getattr(args, "_module", None):
        parser.print_help()
        return 2
    from layouts.errors import InputError
    from mvracklay.parallel import TaskFailed

    mod = sys.modules[args._module]
    try:
        hook = getattr(mod, "config_defaults", None)
        if hook is not None:
            defaults = hook(args, subparsers[name])
            if defaults:  # the command line still wins: parsed again over these defaults
                subparsers[name].set_defaults(**defaults)
                args = parser.parse_args(argv)
        settings = getattr(mod, "SETTINGS", None)  # a command whose options a settings dataclass makes runs on it
        if settings is not None:
            from mvracklay.settings import from_args

            args = from_args(settings, args)
        return int(mod.run(args) or 0)
    except InputError as e:
        print(f"mvracklay {name}: error: {e}", file=sys.stderr)
        return 2
    except TaskFailed as e:  # a task the Ray cluster lost (a worker or node gone): one line, not a traceback
        print(f"mvracklay {name}: error: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        from layouts.publish import WRITE_ERRNOS

        if e.errno not in WRITE_ERRNOS:
            raise
        # a full disk, a quota or a read-only filesystem under a command that stages nothing: one line, not a
        # traceback (the commands that publish outputs say what they kept themselves)
        where = f"{e.filename}: " if e.filename else ""
        print(f"mvracklay {name}: error: {where}cannot write ({e.strerror})", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:
        note = getattr(mod, "RESUME", None) or getattr(mod, "INTERRUPTED", None)
        _close_progress_bars()
        what = "terminated" if isinstance(e, Terminated) else "interrupted"
        print(f"mvracklay {name}: {what}" + (f" ({note})" if note else ""), file=sys.stderr)
        return 143 if isinstance(e, Terminated) else 130


if __name__ == "__main__":
    sys.exit(main())
