"""The architecture page names real files: every repository path it quotes exists."""

import re
from pathlib import Path

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
