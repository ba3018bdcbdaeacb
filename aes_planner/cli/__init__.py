"""The ``aes-planner`` command line.

Each subcommand lives in its own module of this package with a ``register(subparsers)``
function; :data:`COMMANDS` lists them in help order. User errors
(:class:`~aes_planner.errors.AesPlannerError`) print one line and exit with status 2. Any other
exception is a bug: it prints one line asking for a report and exits 2 as well, and with ``-v``
its traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import gc
import importlib
import logging
import os
import sys

from aes_planner import __version__
from aes_planner.errors import AesPlannerError

COMMANDS = [
    "aes_planner.cli.demo",
    "aes_planner.cli.launch",
    "aes_planner.cli.sim",
    "aes_planner.cli.dataset",
    "aes_planner.cli.pose",
    "aes_planner.cli.suggest",
    "aes_planner.cli.eval",
    "aes_planner.cli.bench",
    "aes_planner.cli.warmup",
    "aes_planner.cli.score",
    "aes_planner.cli.teachers",
    "aes_planner.cli.gimbal",
    "aes_planner.cli.drone",
    "aes_planner.cli.calibrate",
    "aes_planner.cli.bus",
    "aes_planner.cli.ros2",
    "aes_planner.cli.export",
    "aes_planner.cli.train",
    "aes_planner.cli.docs",
]


class _Parser(argparse.ArgumentParser):
    """An argument error is one line (``error: ...``, exit 2) like every other error; sub-command
    parsers are of this class too (argparse makes them of their parent's class)."""

    def error(self, message: str):
        self.exit(2, error_line(f"error: {self.prog}: {message} (see {self.prog} --help)") + "\n")


#: Top-level commands registered by a module of another name (every other command ``X`` is
#: registered by ``aes_planner.cli.X``).
COMMAND_MODULES = {name: "aes_planner.cli.bus" for name in ("echo", "topics", "record", "replay", "foxglove")}


def build_parser(modules: list[str] | None = None) -> argparse.ArgumentParser:
    """The CLI's parser with the commands of ``modules`` (default: all of :data:`COMMANDS`)."""
    parser = _Parser(
        prog="aes-planner",
        description="Camera viewpoint suggestion with a 3D aesthetic field.",
    )
    parser.add_argument("--version", action="version", version=f"aes-planner {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS if modules is None else modules:
        importlib.import_module(name).register(sub)
    return parser


def command_module(argv: list[str]) -> str | None:
    """The one module whose parser ``argv`` needs: that of the command it names after the global
    ``-v`` flags; None for anything else (``--help``, ``--version``, no command, an unknown one),
    which gets the whole parser and its list of commands. Building every command's parser imports
    what their options list (the platforms, the presets, the scorers, and torch with them): 2-5 s
    of a start on a loaded machine, paid by every ``gimbal emulate`` a simulated launch starts."""
    for token in argv:
        if token == "--verbose" or (len(token) > 1 and token[0] == "-" and set(token[1:]) == {"v"}):
            continue
        name = COMMAND_MODULES.get(token, f"aes_planner.cli.{token}")
        return name if name in COMMANDS else None
    return None


def drives_servos(run):
    """Run a subcommand that opens a servo device (a :class:`~aes_planner.devices.Gimbal`) under
    the one :func:`~aes_planner.graph.signals.stop_on_signals`: the first SIGTERM or SIGINT
    interrupts it like Ctrl-C (its ``with gimbal:`` blocks turn torque off on the way out), later
    ones wait for that clean-up, and the command exits with 128 + the first signal's number.

    Every subcommand that opens a gimbal carries this (or runs a graph under
    :func:`~aes_planner.graph.runner.run_graph`, which does the same for a loop);
    ``tests/cli/test_servo_signals_sweep.py`` finds them from the code and sends them signals."""

    @functools.wraps(run)
    def wrapped(args: argparse.Namespace) -> int:
        from aes_planner.graph.signals import SignalShutdown, stop_on_signals

        try:
            with stop_on_signals(interrupt=True):
                return run(args)
        except SignalShutdown as exc:
            print(f"{exc}: stopped, torque off", file=sys.stderr, flush=True)
            return exc.exit_code

    wrapped.drives_servos = True
    return wrapped


def terminal_safe(text: str) -> str:
    """``text`` with every non-printable character but newlines escaped (``\\x1b``): what arrives
    from the bus or a file (topic names, error messages quoting them) must not write control
    sequences into a terminal."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() or c == "\n" else repr(c)[1:-1] for c in text)


#: The longest error line the CLI prints: what an error echoes (a 10,000-character frame id, a
#: file's garbage) is cut here, once, for every command.
MAX_ERROR_CHARS = 1000


def error_line(text: str, limit: int = MAX_ERROR_CHARS) -> str:
    """``text`` as the one line the CLI prints for an error: newlines and runs of spaces folded,
    control characters escaped (:func:`terminal_safe`), and cut to ``limit`` characters in the
    middle with a note of how much was left out: the start names the field, the end says what to
    do, and both stay."""
    text = terminal_safe(" ".join(str(text).split()))
    if len(text) <= limit:
        return text
    cut = len(text) - (limit - 40)
    head = (limit - 40) * 2 // 3
    return f"{text[:head]} ... [{cut} characters cut] ... {text[len(text) - (limit - 40 - head) :]}"


def _empty_value(argv: list[str]) -> str | None:
    """The option (or argument) given an empty string, if any: no option of this CLI takes one."""
    for i, token in enumerate(argv):
        if token.startswith("--") and token.endswith("=") and "=" not in token[:-1]:
            return token[:-1]
        if not token.strip():
            return argv[i - 1] if i and argv[i - 1].startswith("-") else f"argument {i + 1}"
    return None


@contextlib.contextmanager
def _graph_domain(domain: int | None):
    """``--domain N`` as ``AES_PLANNER_DOMAIN=N`` while the command runs: the library's bus
    configuration and every process the command starts read it (docs/guides/graphs.md)."""
    if domain is None:
        yield
        return
    from aes_planner.transport.config import DOMAIN_ENV, graph_domain

    graph_domain(domain, "--domain")
    before = os.environ.get(DOMAIN_ENV)
    os.environ[DOMAIN_ENV] = str(domain)
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(DOMAIN_ENV, None)
        else:
            os.environ[DOMAIN_ENV] = before


def collector_for_start_up() -> None:
    """The program's start: the cyclic garbage collector off while it imports. Torch, numba and
    the package are ~210k objects that live as long as the process; each full collection among the
    imports walks all of them again (~0.1 s apiece), ~0.24 s of a cold ``suggest``'s ~1.3 s of
    imports (CPU, 2026-11-29; docs/benchmarks.md, "cold suggest, session 26")."""
    gc.disable()


def collector_after_start_up() -> None:
    """The command is about to run: what the start-up allocated goes to the collector's permanent
    generation (:func:`gc.freeze`), which later collections do not walk, and the collector is on
    again for the command's own garbage."""
    gc.freeze()
    gc.enable()


def collector_for_exit() -> None:
    """The command has ended: every object left is frozen, so the interpreter's shutdown does not
    walk them again in its final collections (~0.3 s of CPU after a ``suggest``). Shutdown still
    runs the ``atexit`` handlers and frees every module; only finalizers of objects in reference
    cycles still alive at exit are not run, which CPython never promises at exit anyway."""
    gc.freeze()


def _program_imports(args: argparse.Namespace) -> None:
    """The modules the command to run lists in its module's ``PROGRAM_IMPORTS``, imported as part
    of the program's start-up (:mod:`aes_planner.cli.suggest` says why)."""
    func = getattr(args, "func", None)
    module = sys.modules.get(getattr(func, "__module__", ""))
    for name in getattr(module, "PROGRAM_IMPORTS", ()):
        importlib.import_module(name)


def main(argv: list[str] | None = None) -> int:
    """The CLI. Without ``argv`` it is the program (the ``aes-planner`` script, ``python -m
    aes_planner``): the process is its own, and it sets the process's garbage collector for a
    start-up of imports and a quick exit (:func:`collector_for_start_up`,
    :func:`collector_after_start_up`, :func:`collector_for_exit`), and starts the look at the
    machine's load its first suggestion takes (:func:`aes_planner.runtime.start_load_window`).
    Called with ``argv`` (tests, other code) it leaves the collector and the load alone."""
    program = argv is None
    if program:
        collector_for_start_up()
        from aes_planner.runtime import start_load_window

        start_load_window()  # the first suggestion's look at the load spans the start-up, not a 50 ms wait
    try:
        return _main(argv, program)
    finally:
        if program:
            collector_for_exit()


def _main(argv: list[str] | None, program: bool) -> int:
    empty = _empty_value([str(a) for a in (sys.argv[1:] if argv is None else argv)])
    if empty is not None:  # `--teacher ''` would otherwise mean "the default" to `args.x or DEFAULT`
        print(f"error: {empty}: an empty value; give one, or leave the option out for its default", file=sys.stderr)
        return 2
    module = command_module([str(a) for a in (sys.argv[1:] if argv is None else argv)])
    parser = build_parser(None if module is None else [module])
    args = parser.parse_args(argv)
    if program:
        _program_imports(args)
        collector_after_start_up()
    level = [logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)]
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        with _graph_domain(getattr(args, "domain", None)):
            return int(args.func(args) or 0)
    except AesPlannerError as exc:
        print(error_line(f"error: {exc}"), file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # Ctrl-C, or a signal stop that ended a command (SignalShutdown)
        return getattr(exc, "exit_code", 130)
    except BrokenPipeError:  # the reader went away (`... | head`): stop quietly, as a shell tool does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit's flush
        return 141
    except Exception as exc:  # a bug: say so in one line; -v keeps the traceback
        if args.verbose:
            raise
        if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
            # a file the command reads or writes (disk full, permissions, a folder where a file
            # was expected): the user's to fix, not a bug
            print(error_line(f"error: {exc.filename}: {exc.strerror}"), file=sys.stderr)
            return 2
        text = error_line(str(exc), 300)
        print(
            f"error: unexpected {type(exc).__name__}: {text} (this is a bug in aes-planner; please report it "
            "with the command line; rerun with -v for the traceback)",
            file=sys.stderr,
        )
        return 2
