"""Run ``lint-imports`` (import-linter: the floors of docs/architecture.md, as contracts in
pyproject.toml) over the package as it installs.

``sim/``, ``drivers/`` and ``launch/`` install as ``aes_planner.sim``, ``aes_planner.drivers`` and
``aes_planner.launch`` (pyproject's ``package-dir``), but import-linter reads a package from one
folder. So the import graph is read from a temporary tree of links laid out as installed: the
entries of ``aes_planner/`` plus one link per mapped folder. Usage: ``python .ci/lint_imports.py``
(``make lint`` runs it); extra arguments go to ``lint-imports``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

try:
    import tomllib
except ImportError:  # Python 3.10: pip vendors the same parser
    from pip._vendor import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent


def main(argv: list[str]) -> int:
    pyproject = ROOT / "pyproject.toml"
    mapping = tomllib.loads(pyproject.read_text())["tool"]["setuptools"]["package-dir"]
    lint_imports = Path(sys.executable).with_name("lint-imports")
    with tempfile.TemporaryDirectory(prefix="lint-imports-") as tree:
        package = Path(tree, "aes_planner")
        package.mkdir()
        for entry in (ROOT / mapping["aes_planner"]).iterdir():
            if entry.name != "__pycache__":
                os.symlink(entry, package / entry.name)
        for name, folder in mapping.items():
            if name.startswith("aes_planner."):
                os.symlink(ROOT / folder, package / name.removeprefix("aes_planner."))
        cmd = [str(lint_imports), "--no-cache", "--no-logo", *argv, str(pyproject)]
        return subprocess.run(cmd, cwd=tree, check=False).returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
