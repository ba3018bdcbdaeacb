"""Which ``aes-planner`` subcommands open a servo device: found from the code, not listed by hand.

:func:`servo_entry_points` walks the CLI's argument parser to every leaf subcommand and follows,
through the source (AST), every function, class and method of the package the command's function
names, transitively. A command opens a servo device when that reaches one of :data:`OPENERS` --
the device factory, the node factory a launch file goes through (a launch may hold a gimbal
node), the multi-process supervisor -- or a :class:`~aes_planner.devices.Gimbal` class. A new
command that opens a gimbal in any of these ways is found without anyone listing it. The walk does
not follow :data:`CAMERA_ONLY`: the camera factory (it goes through the device factory but refuses
anything that is not a :class:`~aes_planner.devices.Camera`) and the reading of a launch file's
camera spec (it parses the graph, which names node classes, and returns a mapping; nothing opens).
"""

from __future__ import annotations

import argparse
import ast
import importlib
import inspect
import textwrap
from collections.abc import Callable

from aes_planner.cli import build_parser
from aes_planner.cli.calibrate import launch_camera_spec
from aes_planner.devices import Gimbal, make_camera, make_device
from aes_planner.graph.base import make_node, node_class
from aes_planner.graph.supervisor import Supervisor

OPENERS = {make_device, node_class, make_node, Supervisor}
#: What reaches :data:`OPENERS` but can only build or describe a camera: not followed.
CAMERA_ONLY = {make_camera, launch_camera_spec}


def leaf_commands(parser: argparse.ArgumentParser | None = None, prefix: str = "") -> dict[str, object]:
    """``{"gimbal move": function, ...}``: every leaf subcommand's ``func``."""
    parser = parser or build_parser()
    out = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out.update(leaf_commands(sub, f"{prefix} {name}".strip()))
    func = parser.get_default("func")
    if func is not None and prefix:
        out[prefix] = func
    return out


def _is_ours(obj) -> bool:
    return getattr(obj, "__module__", "") and obj.__module__.startswith("aes_planner")


def _opener(obj) -> bool:
    if obj in OPENERS:
        return True
    return inspect.isclass(obj) and issubclass(obj, Gimbal) and obj is not Gimbal


def _references(obj) -> list:
    """Package functions and classes named in ``obj``'s source (imports inside it included)."""
    target = inspect.unwrap(obj) if callable(obj) else obj
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(target)))
    except (OSError, TypeError, SyntaxError):
        return []
    module = importlib.import_module(target.__module__)
    scope: dict = dict(vars(module))
    for node in ast.walk(tree):  # imports inside the function (the CLI imports lazily)
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            try:
                mod = importlib.import_module(node.module)
            except ImportError:
                continue
            for alias in node.names:
                try:
                    scope[alias.asname or alias.name] = getattr(mod, alias.name)
                except AttributeError:
                    try:
                        scope[alias.asname or alias.name] = importlib.import_module(f"{node.module}.{alias.name}")
                    except ImportError:
                        pass
        elif isinstance(node, ast.Import):
            for alias in node.names:
                try:
                    scope[alias.asname or alias.name.split(".")[0]] = importlib.import_module(
                        alias.name.split(".")[0] if not alias.asname else alias.name
                    )
                except ImportError:
                    pass
    owner = None
    if inspect.isfunction(target):
        closure = inspect.getclosurevars(target)
        scope.update(closure.nonlocals)
    if inspect.isfunction(target) and "." in target.__qualname__:
        owner = scope.get(target.__qualname__.split(".")[0])
    found = []
    for node in ast.walk(tree):
        value = None
        if isinstance(node, ast.Name):
            value = scope.get(node.id)
        elif isinstance(node, ast.Attribute):
            chain = []
            base = node
            while isinstance(base, ast.Attribute):
                chain.append(base.attr)
                base = base.value
            if isinstance(base, ast.Name):
                value = owner if base.id in ("self", "cls") else scope.get(base.id)
                for attr in reversed(chain):
                    value = getattr(value, attr, None) if value is not None else None
        if value is not None and (inspect.isfunction(value) or inspect.isclass(value) or inspect.ismethod(value)):
            if _is_ours(value):
                found.append(value)
    if inspect.isclass(target):
        for base in target.__mro__[1:]:
            if _is_ours(base):
                found.append(base)
        for member in vars(target).values():
            if isinstance(member, (staticmethod, classmethod)):
                member = member.__func__
            if isinstance(member, property):
                member = member.fget
            if inspect.isfunction(member):
                found.append(member)
    return found


def reaches(func, hit: Callable[[object], bool]) -> bool:
    """Whether ``func``'s code reaches an object for which ``hit`` is true."""
    seen: set = set()
    todo = [func]
    while todo:
        obj = todo.pop()
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        if hit(obj):
            return True
        if obj in CAMERA_ONLY:
            continue
        todo.extend(r for r in _references(obj) if id(r) not in seen)
    return False


def opens_servo_device(func) -> bool:
    """Whether ``func`` (a subcommand's function) can reach a servo device (see the module docstring)."""
    return reaches(func, _opener)


def servo_entry_points() -> dict[str, object]:
    """``{"calibrate rig": function, ...}``: every subcommand that opens a servo device."""
    return {name: f for name, f in leaf_commands().items() if opens_servo_device(f)}


if __name__ == "__main__":  # pragma: no cover - a look at what is found
    for name in servo_entry_points():
        print(name)
