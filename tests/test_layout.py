"""The package's shape: no import cycles, small root modules, one flag spelling.

Static checks (ast and argparse only, nothing compiled): every `import` in every module
of the package, at module level or inside a function, is an edge; the graph must have
no cycle. CLI flags are spelled with underscores (`--num_envs`), as the generated ones.
"""

from __future__ import annotations

import argparse
import ast
import importlib
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "mara_mjx"


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict[str, set[str]]:
    """{module: modules of mara_mjx it imports} (a package import counts as its
    __init__; `from pkg import mod` as `pkg.mod` when that is a module)."""
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text())):
            targets = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                for a in node.names:
                    sub = f"{node.module}.{a.name}"
                    targets.append(sub if sub in modules else node.module)
            for t in targets:
                if t in modules and t != name:
                    graph[name].add(t)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph[n]):
            if state.get(m) == 1:
                return stack[stack.index(m) :] + [m]
            if m not in state and (cycle := visit(m)):
                return cycle
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state and (cycle := visit(n)):
            return cycle
    return None


def test_every_subpackage_is_installed():
    """pyproject's explicit package list names every package folder of mara_mjx (a
    missing one installs without its modules: the plain-install test fails only where
    wheels can be built, so this check runs everywhere)."""
    import tomllib

    listed = set(
        tomllib.loads((PACKAGE.parent / "pyproject.toml").read_text())["tool"]["setuptools"][
            "packages"
        ]
    )
    found = {_module_name(p) for p in PACKAGE.rglob("__init__.py")}
    assert found <= listed, f"add {sorted(found - listed)} to [tool.setuptools] packages"


def test_no_import_cycles():
    graph = import_graph()
    # a package's __init__ re-exporting its modules is not a cycle with them: drop the
    # edges from a module to the __init__ of its own package
    for name, targets in graph.items():
        graph[name] = {t for t in targets if not name.startswith(t + ".")}
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph))


def test_ground_floor_imports_nothing_above_it():
    graph = import_graph()
    allowed = ("mara_mjx.envs", "mara_mjx.config", "mara_mjx.runtime.sharding")
    for name in graph:
        if name.startswith("mara_mjx.envs"):
            above = [t for t in graph[name] if not t.startswith(allowed)]
            assert not above, (name, above)


# the command shims (`python -m mara_mjx.train` ...), the XLA flag and the config machinery
ROOT_MODULES = {"_xla", "config", "train", "evaluate", "pick", "play", "export", "benchmark",
                "plots"}  # fmt: skip
# the shims' targets: each CLI's real module, in its room
COMMANDS = {
    "train": "cli.train",
    "evaluate": "cli.evaluate",
    "pick": "cli.pick",
    "play": "cli.play",
    "export": "cli.export",
    "benchmark": "cli.benchmark",
    "plots": "viz.plots",
}


def test_the_root_holds_the_commands_and_little_else():
    """At most 9 modules beside __init__ and the subpackages (the rooms: cli, adapters,
    deploy, runtime, viz, envs, ppo, bench): the commands, each only starting its CLI,
    config and _xla."""
    root = {p.stem for p in PACKAGE.glob("*.py")} - {"__init__", "__main__"}
    assert root == ROOT_MODULES and len(root) <= 9, sorted(root)
    for command, target in COMMANDS.items():
        text = (PACKAGE / f"{command}.py").read_text()
        assert f'run_module("mara_mjx.{target}", run_name="__main__"' in text, command
        assert (PACKAGE / f"{target.replace('.', '/')}.py").is_file(), target


def test_root_modules_are_small():
    for path in PACKAGE.glob("*.py"):
        lines = len(path.read_text().splitlines())
        assert lines <= 420, f"{path.name} has {lines} lines"


MAX_MODULE_LINES = 450


def test_no_module_is_over_450_lines():
    """Every module of the package reads in one sitting (style.md): at most 450 lines."""
    long = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        name = path.relative_to(PACKAGE.parent).as_posix()
        lines = len(path.read_text().splitlines())
        if lines > MAX_MODULE_LINES:
            long[name] = lines
    assert not long, f"over {MAX_MODULE_LINES} lines, split by responsibility: {long}"


def _parsers() -> list[argparse.ArgumentParser]:
    from mara_mjx.bench import runner

    parsers = [runner.build_parser("")]
    for module in ("train", "evaluate", "play", "export"):
        parsers.append(importlib.import_module(f"mara_mjx.cli.{module}").build_parser())
    parsers.append(importlib.import_module("mara_mjx.cli.train").build_parser(full=True))
    out = []
    while parsers:
        p = parsers.pop()
        out.append(p)
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                parsers += list(action.choices.values())
    return out


@pytest.mark.parametrize("parser", _parsers(), ids=lambda p: p.prog)
def test_flags_have_one_spelling(parser):
    for action in parser._actions:
        for option in action.option_strings:
            if option.startswith("--") and option != "--help" and "-" in option[2:]:
                # only as a hidden alias of an earlier spelling, with a deprecation note
                assert type(action).__name__ == "Deprecated", f"{parser.prog}: {option}"
                assert action.help == argparse.SUPPRESS, f"{parser.prog}: {option} is listed"
