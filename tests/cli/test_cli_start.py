"""A command builds only its own parser: the same parser as in the whole CLI, without importing
what the other commands' options list (the platforms and torch with them)."""

import subprocess
import sys

import pytest

from aes_planner.cli import COMMANDS, build_parser, command_module
from aes_planner.cli.docs import _subparsers


def _helps(parser) -> dict[str, str]:
    """Every (sub)command's help text under ``parser``, by its full name."""
    out = {}

    def walk(prefix, p):
        for name, sub in _subparsers(p):
            out[f"{prefix}{name}"] = sub.format_help()
            walk(f"{prefix}{name} ", sub)

    walk("", parser)
    return out


def test_each_command_alone_parses_as_in_the_whole_cli():
    whole = _helps(build_parser())
    top = sorted({name.split()[0] for name in whole})
    assert len(top) > 15
    for name in top:
        module = command_module([name])
        assert module in COMMANDS, name
        alone = _helps(build_parser([module]))
        mine = {k: v for k, v in whole.items() if k.split()[0] in {n.split()[0] for n in alone}}
        assert name in alone and alone == mine, name


@pytest.mark.parametrize(
    ("argv", "module"),
    [
        (["gimbal", "emulate"], "aes_planner.cli.gimbal"),
        (["-vv", "demo", "--scene", "x"], "aes_planner.cli.demo"),
        (["--verbose", "-v", "echo", "gimbal/state"], "aes_planner.cli.bus"),
        (["--help"], None),
        (["--version"], None),
        (["-x", "demo"], None),  # an unknown global flag: the whole parser says so
        (["bogus"], None),
        (["cli"], None),  # a module of the package that is not a command
        ([], None),
    ],
)
def test_the_command_module_is_found_after_the_global_flags(argv, module):
    assert command_module(argv) == module


def test_starting_the_servo_emulator_does_not_import_torch():
    """Every simulated launch with an emulated gimbal starts `aes-planner gimbal emulate` (it took
    2-11 s on a loaded machine when building the whole parser imported torch)."""
    code = (
        "import sys\n"
        "from aes_planner.cli import main\n"
        "try:\n"
        "    main(['gimbal', 'emulate', '--help'])\n"
        "except SystemExit as exc:\n"
        "    assert exc.code == 0, exc.code\n"
        "print(sorted(m for m in ('torch', 'numba', 'aes_planner.platform') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout
