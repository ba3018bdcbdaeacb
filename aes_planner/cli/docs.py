"""``aes-planner docs wire|commands``: the parts of docs/ generated from the code.

* ``wire``: docs/wire.md's topic table (from every node type's declared inputs and outputs, and
  the channels a recording writes for each) and its layout of every message type (from the field
  tables, :mod:`aes_planner.messages.spec`).
* ``commands``: docs/guides/commands.md, the command-line reference, from the argument parsers.

Each generated part sits between ``<!-- generated: NAME -->`` and ``<!-- end generated: NAME -->``
in its page. Without options the generated text is printed; ``--update FILE`` rewrites those parts
of FILE in place, ``--check FILE`` exits 1 when they differ from the code (tests run the check).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from aes_planner.errors import AesPlannerError

__all__ = ["GENERATED", "commands_markdown", "regions", "replace_regions", "topics_markdown"]


class DocsError(AesPlannerError):
    """A page without the markers of a generated part, or one whose generated part is stale."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "docs",
        help="print (or update, or check) the parts of docs/ generated from the code",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("page", choices=sorted(GENERATED), help="wire: docs/wire.md; commands: docs/guides/commands.md")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--update", metavar="FILE", help="rewrite the generated parts of FILE in place")
    group.add_argument("--check", metavar="FILE", help="exit 1 when the generated parts of FILE are stale")
    p.set_defaults(func=run)


def topics_markdown() -> str:
    """The topic table: every topic a node type declares, its type, QoS, who publishes and reads
    it, and the channels a recording (and the live Foxglove view) shows it on."""
    from aes_planner.graph.base import NODE_TYPES, input_specs, node_class, output_specs
    from aes_planner.transport.foxglove_view import view_channels

    topics: dict[str, dict] = {}
    for word in sorted(NODE_TYPES):
        cls = node_class(word)
        for topic, spec in output_specs(cls).items():
            t = topics.setdefault(topic, {"type": spec.msg_type, "out": [], "in": [], "qos": set()})
            t["out"].append(word)
            t["qos"].add(("latched, " if spec.latched else "") + ("reliable" if spec.reliable else "best effort"))
        for topic, spec in input_specs(cls).items():
            t = topics.setdefault(topic, {"type": spec.msg_type, "out": [], "in": [], "qos": set()})
            t["in"].append(word)
    from aes_planner.graph.clock import ACK_TOPIC, CLOCK_TOPIC
    from aes_planner.messages.clock import Clock, ClockAck

    # the graph's own topics (a launch with `clock: sim`): not a node type's declarations
    graph_topics = {
        CLOCK_TOPIC: (Clock, "latched, reliable", "the graph's clock (`clock: sim` launches)", "every node"),
        ACK_TOPIC: (ClockAck, "reliable", "every node, on a simulated clock", "the graph's clock"),
    }
    for topic, (msg_type, qos, out, reads) in graph_topics.items():
        topics[topic] = {"type": msg_type, "out": [], "in": [], "qos": {qos}, "out_text": out, "in_text": reads}
    lines = [
        "| topic | type | QoS | published by | read by | recording channels |",
        "|---|---|---|---|---|---|",
    ]
    for topic in sorted(topics):
        t = topics[topic]
        channels = [f"/{topic}"] + [c for c, _, _ in view_channels(topic, t["type"])]
        out = t.get("out_text") or ", ".join(f"`{w}`" for w in t["out"]) or "you (no node type publishes it)"
        reads = t.get("in_text") or ", ".join(f"`{w}`" for w in t["in"]) or "you"
        qos = " / ".join(sorted(t["qos"])) or "(as you publish it)"
        lines.append(
            f"| `{topic}` | `{t['type'].TYPE_NAME}` | {qos} | {out} | {reads} | {', '.join(f'`{c}`' for c in channels)} |"
        )
    return "\n".join(lines) + "\n"


def commands_markdown() -> str:
    """The command-line reference: every command and subcommand's usage and options, from the
    argument parsers (argparse's own help text, so it is what ``--help`` prints)."""
    import os

    from aes_planner.cli import build_parser

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"  # argparse wraps to the terminal: the page must not depend on it
    try:
        parser = build_parser()
        parser.prog = "aes-planner"
        out = ["## `aes-planner`", "", "```text", _help(parser), "```", ""]
        for name, sub in _subparsers(parser):
            out += _command(f"aes-planner {name}", sub, 2)
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old
    return "\n".join(out).rstrip("\n") + "\n"


def _subparsers(parser: argparse.ArgumentParser) -> list[tuple[str, argparse.ArgumentParser]]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return list(action.choices.items())
    return []


def _help(parser: argparse.ArgumentParser) -> str:
    # Python 3.10's argparse titles the options "optional arguments:"; later ones "options:"
    return parser.format_help().rstrip().replace("\noptional arguments:\n", "\noptions:\n")


def _command(name: str, parser: argparse.ArgumentParser, depth: int) -> list[str]:
    lines = [f"{'#' * min(depth + 1, 4)} `{name}`", "", "```text", _help(parser), "```", ""]
    for sub_name, sub in _subparsers(parser):
        lines += _command(f"{name} {sub_name}", sub, depth + 1)
    return lines


def _wire() -> dict[str, str]:
    from aes_planner.messages.spec import wire_types_markdown

    return {"wire-topics": topics_markdown(), "wire-types": wire_types_markdown()}


#: page -> the function giving its generated parts ({region name: markdown}).
GENERATED = {"wire": _wire, "commands": lambda: {"commands": commands_markdown()}}


def regions(page: str) -> dict[str, str]:
    """``{region name: generated markdown}`` of ``page`` (``wire`` or ``commands``)."""
    return GENERATED[page]()


def _pattern(name: str) -> re.Pattern:
    return re.compile(
        rf"(<!-- generated: {re.escape(name)}\b[^>]*-->\n)(.*?)(<!-- end generated: {re.escape(name)} -->)", re.S
    )


def replace_regions(text: str, parts: dict[str, str], where: str = "the page") -> str:
    """``text`` with each generated part replaced by ``parts[name]``; :class:`DocsError` when a
    part's markers are missing."""
    for name, body in parts.items():
        pattern = _pattern(name)
        if not pattern.search(text):
            raise DocsError(
                f"{where} has no generated part {name!r}: add the lines '<!-- generated: {name} -->' and "
                f"'<!-- end generated: {name} -->' where it goes"
            )
        text = pattern.sub(lambda m, body=body: m.group(1) + "\n" + body + "\n" + m.group(3), text)
    return text


def run(args: argparse.Namespace) -> int:
    parts = regions(args.page)
    if args.update is None and args.check is None:
        for name, body in parts.items():
            print(f"<!-- generated: {name} -->\n\n{body}\n<!-- end generated: {name} -->\n")
        return 0
    path = Path(args.update or args.check)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise DocsError(f"{path}: cannot read it ({exc.strerror}); give the page to update") from None
    new = replace_regions(text, parts, str(path))
    if args.check is not None:
        if new != text:
            stale = [n for n, body in parts.items() if _pattern(n).search(text).group(2) != "\n" + body + "\n"]
            print(
                f"{path}: stale generated parts: {', '.join(stale)}; run aes-planner docs {args.page} --update {path}"
            )
            return 1
        print(f"{path}: the generated parts match the code")
        return 0
    if new != text:
        path.write_text(new, encoding="utf-8")
        print(f"{path}: updated {', '.join(parts)}")
    else:
        print(f"{path}: already up to date")
    return 0
