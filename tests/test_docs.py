"""The architecture page is true: every repository path it quotes exists, and its floors are the
import-linter contract CI enforces."""

import re
import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10: pip vendors the same parser
    from pip._vendor import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent


def test_every_path_the_architecture_page_names_exists():
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    quoted = re.findall(r"`([^`\s]+)`", text)
    roots = ("aes_planner/", "drivers/", "sim/", "docs/", "tests/", "launch/", "ros2/")
    paths = [q for q in quoted if q.startswith(roots)]  # topics (camera/frame) are not paths
    assert len(paths) > 20  # the page is about files; an empty match would prove nothing
    missing = [p for p in paths if not (ROOT / p).exists()]
    assert not missing, f"docs/architecture.md names paths that do not exist: {missing}"
    links = re.findall(r"\]\(([^)#]+)\)", text)
    assert not [p for p in links if not (ROOT / "docs" / p).exists()], "a link of docs/architecture.md is broken"


def _module(path: str) -> str:
    """``aes_planner/geometry/`` or ``aes_planner/images.py`` -> its module name."""
    return path.rstrip("/").removesuffix(".py").replace("/", ".")


def test_the_floor_table_is_the_layers_contract():
    """The page's floors, row by row from the ground, are the layers of ``[tool.importlinter]``
    that ``make lint`` checks; a package in neither, or on a different floor, fails here."""
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    table = text[text.index("## The floors") : text.index("## Rules no floor breaks")]
    rows = re.findall(r"^\| (\d+) \| (.+?) \| .+\|$", table, flags=re.M)
    page = {int(n): {_module(p) for p in re.findall(r"`(aes_planner/[^`]+)`", cell)} for n, cell in rows}
    assert sorted(page) == list(range(len(page))) and len(page) > 10
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["importlinter"]
    (layers,) = [c["layers"] for c in config["contracts"] if c["type"] == "layers"]
    contract = {i: set(re.split(r"\s*[|:]\s*", layer)) for i, layer in enumerate(reversed(layers))}
    assert page == contract
    # every module of the package is on a floor (or beside them: sim, drivers, launch)
    tops = {p.stem if p.suffix == ".py" else p.name for p in (ROOT / "aes_planner").iterdir()}
    tops -= {"__init__", "__main__", "__pycache__"}
    placed = {m.split(".")[1] for floor in page.values() for m in floor}
    assert not sorted(tops - placed), f"not on any floor of docs/architecture.md: {sorted(tops - placed)}"


def test_docs_wire_check_and_update_as_a_user_runs_them(tmp_path, capsys):
    """``aes-planner docs wire --check`` passes on the committed page, fails (1) on a stale copy
    and names the part; ``--update`` makes the copy current; a page without the markers is an
    error naming them (2). The first check runs as a user runs it, in its own process (the exit
    status of ``python -m aes_planner``); the others call the same ``main`` in this process, which
    returns the status the process exits with (aes_planner/__main__.py): each process start cost
    6-9 s at load 12."""
    import subprocess

    from aes_planner.cli import main

    page = ROOT / "docs" / "wire.md"
    ok = subprocess.run(
        [sys.executable, "-m", "aes_planner", "docs", "wire", "--check", str(page)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert ok.returncode == 0, ok.stdout + ok.stderr
    stale = tmp_path / "wire.md"
    stale.write_text(page.read_text(encoding="utf-8").replace("| `stamp_s` | f64 |", "| `stamp_s` | f32 |", 1))
    capsys.readouterr()
    assert main(["docs", "wire", "--check", str(stale)]) == 1
    assert "wire-types" in capsys.readouterr().out
    assert main(["docs", "wire", "--update", str(stale)]) == 0
    assert stale.read_text(encoding="utf-8") == page.read_text(encoding="utf-8")
    bare = tmp_path / "bare.md"
    bare.write_text("# nothing generated here\n")
    assert main(["docs", "wire", "--check", str(bare)]) == 2
    assert "<!-- generated: wire-topics -->" in capsys.readouterr().err


def test_the_command_reference_is_the_argument_parsers():
    """docs/guides/commands.md's reference is what ``--help`` prints for every command today
    (an option added to a parser but not to the page fails here; fix with ``aes-planner docs
    commands --update docs/guides/commands.md``)."""
    from aes_planner.cli import build_parser
    from aes_planner.cli.docs import _subparsers, regions, replace_regions

    page = (ROOT / "docs" / "guides" / "commands.md").read_text(encoding="utf-8")
    assert replace_regions(page, regions("commands")) == page, "run: aes-planner docs commands --update ..."
    names = [name for name, _ in _subparsers(build_parser())]
    assert len(names) > 15 and all(f"### `aes-planner {n}`" in page for n in names)


def test_every_relative_link_of_the_docs_resolves():
    """README.md and every page of docs/ (the work logs aside) link only to files that exist."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    broken = []
    for page in pages:
        if "journal" in page.parts:
            continue
        text = re.sub(r"```.*?```", "", page.read_text(encoding="utf-8"), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"^(https?:|#|mailto:)", target):
                continue
            if not (page.parent / target.partition("#")[0]).exists():
                broken.append(f"{page.relative_to(ROOT)} -> {target}")
    assert len(pages) > 10 and not broken, broken


def test_the_readme_maps_every_guide():
    """Every page of docs/guides/ is on the README's map (a guide nobody can find is not read)."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    guides = sorted(p.name for p in (ROOT / "docs" / "guides").glob("*.md"))
    assert len(guides) > 10
    assert not [g for g in guides if f"(docs/guides/{g})" not in readme], "add the guide to the README's map"
