"""Entry point of the ``roodi-toolkit`` command.

Conventions every command follows: one line on stderr for any failure, no traceback unless ``--debug`` (accepted
anywhere on the line); outputs are written atomically, never over an input, and over an existing file only with
``--overwrite`` (a file that appears at an output while the command runs is left alone and the command refuses); a
command's outputs appear together or not at all (:data:`GROUPED_COMMANDS`). Kinds of failure
(:mod:`roodi_toolkit.errors`) and exit codes:

====  ==========================================================================================================
exit  when
====  ==========================================================================================================
0     success (also ``--help`` and ``--version``)
1     ``InputError`` (a file or option the user gave: ``PlyError``, ``CloudError``, ``DatasetError``,
      ``ConfigError``, ``OutputError``, ``UnsupportedFormatError``), ``PluginError``, any other ``RoodiError``
1     an environment problem, ``EnvironmentProblemError`` or an ``OSError`` on an output with ENOSPC / EDQUOT
      (disk full), EROFS (read-only folder), EACCES / EPERM (not allowed), or an ``ImportError`` of a missing
      system library (``lib*.so``) or Python package: the message names the problem and what to do
1     out of memory, or an unexpected error (the message asks to rerun with ``--debug`` and report it)
2     usage errors: an unknown option, a missing argument, a value click rejects
130   interrupted (Ctrl-C)
143   terminated (SIGTERM; 129 for SIGHUP, a closed terminal): as with Ctrl-C, no output appears half made
====  ==========================================================================================================

Commands are imported only when run (``--help`` reads their short help from their modules' source), so
``roodi-toolkit info`` stays fast; a command's module imports what it runs at its top.
"""

from __future__ import annotations

import ast
import contextlib
import importlib
import importlib.util
import io
import math
import os
import signal
import sys
import threading
import warnings
from pathlib import Path
from typing import Any, Iterator, Sequence

import click

from roodi_toolkit._version import __version__
from roodi_toolkit.cli.common import say_above_bars, set_torch_threads, threads_setting
from roodi_toolkit.errors import InputWarning, RoodiError, missing_library_problem, os_error_problem
from roodi_toolkit.io.files import output_group
from roodi_toolkit.progress import tell_first_compile
from roodi_toolkit.signals import deferrable

# name -> "module:attribute" of a click.Command. One line per command.
COMMANDS: dict[str, str] = {
    "batch": "roodi_toolkit.cli.cmd_batch:batch",
    "benchmark": "roodi_toolkit.cli.cmd_benchmark:benchmark",
    "convert": "roodi_toolkit.cli.cmd_convert:convert",
    "demo": "roodi_toolkit.cli.cmd_demo:demo",
    "evaluate": "roodi_toolkit.cli.cmd_evaluate:evaluate",
    "extract": "roodi_toolkit.cli.cmd_extract:extract",
    "info": "roodi_toolkit.cli.cmd_info:info",
    "inspect": "roodi_toolkit.cli.cmd_inspect:inspect",
    "plugins": "roodi_toolkit.cli.cmd_plugins:plugins",
    "prune": "roodi_toolkit.cli.cmd_prune:prune",
    "render": "roodi_toolkit.cli.cmd_render:render",
    "train": "roodi_toolkit.cli.cmd_train:train",
    "make-scene": "roodi_toolkit.cli.cmd_make_scene:make_scene",
    "distill": "roodi_toolkit.cli.cmd_distill:distill",
    "select": "roodi_toolkit.cli.cmd_select:select",
}

EPILOG = ("Add --debug anywhere for a full traceback on errors, --threads N for N PyTorch threads (default 1, or "
          "$ROODI_THREADS), -q for no progress bars. Docs: README.md.")


class LazyGroup(click.Group):
    """A click group whose commands named in ``lazy`` (name -> ``"module:attribute"``; the package's
    :data:`COMMANDS` by default) are imported on first use, beside any it holds itself (``batch``'s light tasks)."""

    def __init__(self, *args: Any, lazy: dict[str, str] | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.lazy = COMMANDS if lazy is None else lazy

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(self.commands) | set(self.lazy))

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """List the commands with their short help, that of lazy ones read from the source of their modules: listing
        them imports none of them (each imports what it runs at its top: ``train`` imports torch)."""
        names = self.list_commands(ctx)
        limit = formatter.width - 6 - max(len(name) for name in names)
        with formatter.section("Commands"):
            formatter.write_dl([(name, self.commands[name].get_short_help_str(limit) if name in self.commands
                                 else _short_help(self.lazy[name], limit)) for name in names])

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name in self.commands:
            return self.commands[name]
        target = self.lazy.get(name)
        if target is None:
            return None
        module_name, attr = target.split(":")
        return _finite_floats(getattr(importlib.import_module(module_name), attr))


def _short_help(target: str, limit: int) -> str:
    """Return the short help of the command ``module:attribute`` as click makes it from the docstring of the
    function the command decorates, found in the module's source without importing it."""
    module_name, attr = target.split(":")
    spec = importlib.util.find_spec(module_name)
    tree = ast.parse(Path(spec.origin).read_text(encoding="utf-8"))
    doc = next(ast.get_docstring(node, clean=False) for node in tree.body
               if isinstance(node, ast.FunctionDef) and node.name == attr)
    return click.Command(attr, help=doc).get_short_help_str(limit)


class FiniteFloat(click.ParamType):
    """Wraps a command's float type (``float`` or a ``FloatRange``): also refuses NaN and +-inf. Click's ranges let
    NaN through (every comparison with it is false): ``--classifier-lr nan`` reached the optimiser."""

    def __init__(self, inner: click.ParamType) -> None:
        self.inner = inner
        self.name = inner.name

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        out = self.inner.convert(value, param, ctx)
        if isinstance(out, float) and not math.isfinite(out):
            self.fail(f"must be a finite number, got {value!r}", param, ctx)
        return out

    def get_metavar(self, param: click.Parameter, *args: Any, **kwargs: Any) -> str | None:
        return self.inner.get_metavar(param, *args, **kwargs)

    def to_info_dict(self) -> dict[str, Any]:
        return self.inner.to_info_dict()

    def __repr__(self) -> str:
        return repr(self.inner)


SEED_RANGE = click.IntRange(0, 2 ** 32 - 1)
"""Every ``--seed``: NumPy's generators refuse negative seeds (``--seed -1`` was an unexpected ValueError) and
NumPy's legacy and PyTorch's seeding stop at 32 and 64 bits."""


def _finite_floats(command: click.Command) -> click.Command:
    """Make every float option and argument of ``command`` refuse non-finite values, and every ``--seed`` a value
    outside :data:`SEED_RANGE` (once per command object; the options a
    :class:`~roodi_toolkit.cli.settings.SettingsCommand` makes later, once made)."""
    finishers = getattr(command, "finishers", None)
    if finishers is not None and _finite_floats not in finishers:
        finishers.append(_finite_floats)
    for param in command.made_params if hasattr(command, "made_params") else command.params:
        if isinstance(param.type, click.types.FloatParamType):
            param.type = FiniteFloat(param.type)
        elif param.name == "seed" and type(param.type) is click.types.IntParamType:
            param.type = SEED_RANGE
    if isinstance(command, click.Group):  # batch's sub-commands
        for sub in command.commands.values():
            _finite_floats(sub)
    return command


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 110},
             epilog=EPILOG)
@click.version_option(__version__, "--version", prog_name="roodi-toolkit")
def app() -> None:
    """roodi-toolkit: take one object out of a 3D Gaussian Splatting scene as a clean, standalone 3DGS model.

    \b
    Examples:
      roodi-toolkit info scene.ply
      roodi-toolkit prune in.ply out.ply --floaters-out floaters.ply
      roodi-toolkit plugins
    """


# Commands whose outputs appear together or not at all: each runs inside one output group (roodi_toolkit.io.atomic),
# its finished files put in place together at its end, none on an error, a signal or a full disk. Not train (its
# checkpoints must land as they are made), extract and benchmark (stages and scores kept for a re-run to reuse),
# batch (each item's output is its own), demo (its steps are commands of their own).
GROUPED_COMMANDS = frozenset({"convert", "distill", "evaluate", "inspect", "make-scene", "prune", "render", "select"})


def _output_scope(args: Sequence[str]) -> Any:
    """Return the context a command runs in: for :data:`GROUPED_COMMANDS` an output group, with what the command
    prints on stdout ("wrote OUT") held back until its outputs are in place; else nothing."""
    command = next((a for a in args if not a.startswith("-")), None)
    if command not in GROUPED_COMMANDS:
        return contextlib.nullcontext()
    return _grouped()


@contextlib.contextmanager
def _grouped() -> Iterator[None]:
    said = io.StringIO()
    with output_group(), contextlib.redirect_stdout(said):
        yield
    sys.stdout.write(said.getvalue())
    sys.stdout.flush()


def _forget_claims() -> None:
    """Forget the output paths a previous command (in this process: tests, notebooks) checked."""
    files = sys.modules.get("roodi_toolkit.io.files")
    if files is not None:
        files.forget_claims()


# Commands whose work is PyTorch (rendering, training, fine-tuning): they run with ROODI_THREADS intra-op threads.
TORCH_COMMANDS = frozenset({"benchmark", "demo", "distill", "evaluate", "extract", "render", "select", "train"})
# Commands that load PyTorch only to render (the photo check, the floater picture): they set the threads then.
LAZY_TORCH_COMMANDS = frozenset({"prune", "inspect"})


def _torch_threads(args: Sequence[str]) -> None:
    """Set PyTorch's intra-op threads for the torch commands (:func:`roodi_toolkit.cli.common.set_torch_threads`:
    ``--threads N`` or ``$ROODI_THREADS``, default 1). ``prune`` and ``inspect`` load PyTorch only to render and
    set them there; the value is checked here first."""
    if any(a in LAZY_TORCH_COMMANDS for a in args):
        threads_setting()  # they load PyTorch only to render: a bad value is still refused before any work
    if any(a in TORCH_COMMANDS for a in args):
        set_torch_threads()


def _pop_threads(args: list[str]) -> list[str]:
    """Move a global ``--threads N`` (anywhere on the line) into ``$ROODI_THREADS``; return the other arguments."""
    out, i = [], 0
    while i < len(args):
        if args[i] == "--threads" and i + 1 < len(args):
            os.environ["ROODI_THREADS"] = args[i + 1]
            i += 2
            continue
        if args[i].startswith("--threads="):
            os.environ["ROODI_THREADS"] = args[i].split("=", 1)[1]
        else:
            out.append(args[i])
        i += 1
    return out


def _pop_quiet(args: list[str]) -> tuple[list[str], bool]:
    """Take ``-q`` / ``--quiet`` out of the line wherever it stands (before the command too, and on commands without
    progress bars); the commands' ``-q`` reads it from the context (:data:`~roodi_toolkit.cli.common.quiet_option`)."""
    out = [a for a in args if a not in ("-q", "--quiet")]
    return out, len(out) != len(args)


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


class Terminated(BaseException):
    """SIGTERM (or SIGHUP, a closed terminal) arrived: unwinds like Ctrl-C, so that half-written temporary outputs
    are removed on the way out. ``signum`` gives the exit code, 128 + signum."""

    def __init__(self, signum: int = signal.SIGTERM) -> None:
        super().__init__(signum)
        self.signum = int(signum)


def _on_signals() -> dict[int, Any] | None:
    """Make SIGTERM and SIGHUP raise :class:`Terminated` and Ctrl-C ``KeyboardInterrupt`` (in the main thread only),
    all held while outputs are put in place (:mod:`roodi_toolkit.signals`); return the handlers they replace. A
    signal that is ignored (SIGINT in a background job, SIGHUP under nohup) stays ignored."""
    def handler(signum: int, frame: Any) -> None:
        raise Terminated(signum)

    if threading.current_thread() is not threading.main_thread():
        return None
    previous = {signal.SIGTERM: signal.signal(signal.SIGTERM, deferrable(handler))}
    hup = getattr(signal, "SIGHUP", None)
    if hup is not None and signal.getsignal(hup) is signal.SIG_DFL:
        previous[hup] = signal.signal(hup, deferrable(handler))
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, deferrable(signal.default_int_handler))
    return previous


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI and return its exit code (also used as the console script)."""
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    args, quiet = _pop_quiet(_pop_threads([a for a in args if a != "--debug"]))
    previous = _on_signals()
    _forget_claims()
    # NumPy's numerical warnings (overflow, invalid value) on extreme values are not lines for the user: every
    # command checks the values it needs and says what is wrong in one line; --debug shows them
    numbers = warnings.catch_warnings()
    numbers.__enter__()
    if not debug:
        warnings.simplefilter("ignore", RuntimeWarning)
    restore_warnings = _show_input_warnings()
    tell_first_compile(None if quiet else say_above_bars)  # the first render's compile (half a minute) said
    try:
        _torch_threads(args)
        with _output_scope(args):
            app.main(args=args, prog_name="roodi-toolkit", standalone_mode=False, obj={"quiet": quiet})
        return 0
    except click.exceptions.Exit as exc:  # --help / --version
        return int(exc.exit_code or 0)
    except click.exceptions.Abort:
        click.echo("aborted", err=True)
        return 130
    except click.ClickException as exc:  # usage errors: bad option, missing argument, bad value
        if debug:
            raise
        # one line, like every other failure: the message names the option; --help shows the usage
        ctx = getattr(exc, "ctx", None)
        where = ctx.command_path if ctx is not None else "roodi-toolkit"
        click.echo(f"error: {_one_line(exc.format_message())} (see {where} --help)", err=True)
        return int(exc.exit_code) if exc.exit_code else 2
    except RoodiError as exc:
        if debug:
            raise
        click.echo(f"error: {_one_line(str(exc))}", err=True)
        return 1
    except KeyboardInterrupt:
        click.echo("interrupted", err=True)
        return 130
    except Terminated as exc:
        click.echo("terminated" if exc.signum == signal.SIGTERM else f"terminated ({signal.Signals(exc.signum).name})",
                   err=True)
        return 128 + exc.signum
    except MemoryError:
        if debug:
            raise
        click.echo("error: out of memory; try a smaller input or fewer views", err=True)
        return 1
    except Exception as exc:  # noqa: BLE001 - the last line of defence against tracebacks
        if debug:
            raise
        problem = _environment_problem(exc)
        if problem is not None:
            click.echo(f"error: environment problem: {problem}", err=True)
            return 1
        click.echo(f"error: unexpected {type(exc).__name__}: {_one_line(str(exc))} (rerun with --debug for the "
                   "traceback and please report it)", err=True)
        return 1
    finally:
        tell_first_compile(None)
        restore_warnings()
        numbers.__exit__(None, None, None)
        _forget_claims()
        for signum, handler in (previous or {}).items():
            signal.signal(signum, handler)


def _show_input_warnings() -> Any:
    """Show the library's :class:`~roodi_toolkit.errors.InputWarning` (what an input lacked, what was assumed) as one
    ``warning:`` line on stderr each, every time; return the function that puts the previous display back."""
    shown, filters = warnings.showwarning, list(warnings.filters)

    def show(message: Any, category: type, filename: str, lineno: int, file: Any = None, line: Any = None) -> None:
        if issubclass(category, InputWarning):
            click.echo(f"warning: {_one_line(str(message))}", err=True)
        else:
            shown(message, category, filename, lineno, file, line)

    warnings.showwarning = show
    warnings.simplefilter("always", InputWarning)

    def restore() -> None:
        warnings.showwarning = shown
        warnings.filters[:] = filters

    return restore


def _environment_problem(exc: BaseException) -> str | None:
    """Return what the machine lacks, and what to do, for an error that is the environment's fault; else None."""
    if isinstance(exc, OSError):
        problem = os_error_problem(exc)
        if problem is not None:
            return problem
    if isinstance(exc, (ImportError, OSError)):
        problem = missing_library_problem(exc)
        if problem is not None:
            return problem
    if isinstance(exc, ModuleNotFoundError) and exc.name:
        package = exc.name.split(".")[0]
        return f"the Python package {package!r} is not installed; install it (pip install {package}) or reinstall " \
            "roodi-toolkit with its dependencies"
    return None


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
