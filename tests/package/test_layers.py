"""The package's layers, declared once and checked for every module: an import points to the importer's own
layer or a lower one (imports inside functions included), no module imports another subpackage's private
module (``_name``), and the import graph has no cycle.

The layers, lowest first (``LAYERS``; docs/getting-started.md's "Layers" table shows the same, checked below):

====  =====================================================================================================
0     ``params`` and the shared private helpers ``softpvtol_gym._*`` (layouts, series, cache, validation, ...)
1     ``model/``: the compiled physics kernels
2     ``dynamics``, ``integrators``, ``references``: the batched model, integration, the paper's trajectory
3     ``tasks``, ``registry``: the task and tier registries
4     ``control/``: the passivity law, allocation, closed loops, the extended loop, the MPC's problem
5     ``envs/``: the single and vector env, the SB3 adapter, tiers, reward, observation
6     ``policies/``: ``predict`` on observations (passivity, extended, MPC)
7     ``baselines/`` and the package's ``__init__`` (the public names): training, evaluation, the command
====  =====================================================================================================
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "softpvtol_gym"
TOP = "softpvtol_gym"

#: (layer, module or subpackage prefixes); a module belongs to the longest prefix that names it
LAYERS: tuple[tuple[int, tuple[str, ...]], ...] = (
    (0, ("params", "_batching", "_cache", "_columns", "_parallel", "_series_coefficients", "_validation", "_version")),
    (1, ("model",)),
    (2, ("dynamics", "integrators", "references")),
    (3, ("tasks", "registry")),
    (4, ("control",)),
    (5, ("envs",)),
    (6, ("policies",)),
    (7, ("baselines", "")),  # "": the package's __init__
)


def layer_of(module: str) -> int:
    """The layer of a module ``softpvtol_gym.a.b``; KeyError for a module no layer names."""
    rel = module[len(TOP) + 1:] if module != TOP else ""
    best = None
    for layer, prefixes in LAYERS:
        for prefix in prefixes:
            if rel == prefix or (prefix and rel.startswith(prefix + ".")):
                if best is None or len(prefix) > len(best[1]):
                    best = (layer, prefix)
    if best is None:
        raise KeyError(f"{module} is in no layer: add it to LAYERS")
    return best[0]


def module_names(package: Path = PACKAGE) -> dict[str, Path]:
    out = {}
    for path in sorted(package.rglob("*.py")):
        parts = path.relative_to(package.parent).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def imports_of(module: str, source: str, is_package: bool, known: set[str]) -> list[tuple[str, int]]:
    """(imported module, line) for every import in ``source`` (anywhere: module top, functions, classes), relative
    imports resolved, ``from pkg import name`` resolved to the submodule ``pkg.name`` where there is one, and
    ``importlib.import_module("...")`` with a literal name counted as an import."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = module.split(".") if is_package else module.split(".")[:-1]
                anchor = anchor[:len(anchor) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            out += [(f"{base}.{a.name}" if f"{base}.{a.name}" in known else base, node.lineno) for a in node.names]
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "import_module"
              and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            out.append((node.args[0].value, node.lineno))
    return [(name, line) for name, line in out if name == TOP or name.startswith(TOP + ".")]


def _private_owner(module: str) -> str | None:
    """The subpackage a private module belongs to (``a.b._c`` -> ``a.b``), or None if the module is public or
    one of the top-level shared helpers ``softpvtol_gym._*``."""
    parts = module.split(".")
    for i, part in enumerate(parts[1:], start=1):
        if part.startswith("_") and not part.startswith("__"):
            owner = ".".join(parts[:i])
            return None if owner == TOP else owner
    return None


def check(sources: dict[str, tuple[str, bool]]) -> tuple[list[str], list[str], dict[str, set[str]]]:
    """(upward imports, private imports across subpackages, module graph) of ``{module: (source, is_package)}``."""
    known = set(sources)
    upward, private, graph = [], [], {}
    for module, (source, is_package) in sources.items():
        edges = set()
        for target, line in imports_of(module, source, is_package, known):
            if layer_of(target) > layer_of(module):
                upward.append(f"{module}:{line} imports {target} (layer {layer_of(module)} -> {layer_of(target)})")
            owner = _private_owner(target)
            if owner is not None and not (module == owner or module.startswith(owner + ".")):
                private.append(f"{module}:{line} imports {target}, private to {owner}")
            if target in known and target != module:
                edges.add(target)
        graph[module] = edges
    return upward, private, graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = 1
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt, path + [nxt])):
                return found
        state[node] = 2
        return None

    for node in sorted(graph):
        if node not in state and (found := visit(node, [node])):
            return found
    return None


def _package_sources() -> dict[str, tuple[str, bool]]:
    return {name: (path.read_text(encoding="utf-8"), path.name == "__init__.py")
            for name, path in module_names().items()}


SOURCES = _package_sources()


def test_every_module_is_in_a_layer():
    assert len(SOURCES) > 100
    assert {name: layer_of(name) for name in SOURCES}  # KeyError names a module no layer holds


def test_no_import_points_to_a_higher_layer():
    upward, _, _ = check(SOURCES)
    assert upward == []


def test_no_module_imports_another_subpackages_private_module():
    _, private, _ = check(SOURCES)
    assert private == []


def test_the_import_graph_has_no_cycle():
    _, _, graph = check(SOURCES)
    assert sum(map(len, graph.values())) > 200
    assert find_cycle(graph) is None


@pytest.mark.parametrize("module, source, expect", [
    # an upward import inside a function (deferred) is found
    ("softpvtol_gym.control.mpc.ocp", "def f():\n    from ...policies import MPCPolicy\n", "upward"),
    ("softpvtol_gym.model.rk4", "import importlib\nimportlib.import_module('softpvtol_gym.envs')\n", "upward"),
    # another subpackage's private module
    ("softpvtol_gym.envs.step", "from ..control import _block_kernels\n", "private"),
    ("softpvtol_gym.policies.mpc", "from ..control.mpc._casadi import import_casadi\n", "private"),
])
def test_the_checks_find_a_planted_violation(module, source, expect):
    upward, private, _ = check({**SOURCES, module: (source, False)})
    assert (upward if expect == "upward" else private), (module, source)


def test_the_cycle_check_finds_a_planted_cycle():
    _, _, graph = check(SOURCES)
    graph["softpvtol_gym.params"] = graph["softpvtol_gym.params"] | {"softpvtol_gym.envs.step"}
    assert find_cycle(graph) is not None


def test_allowed_imports_are_not_flagged():
    """Same layer, a lower layer, the subpackage's own private modules and the shared ``softpvtol_gym._*``."""
    ok = {
        "softpvtol_gym.control.allocation": ("from . import _allocation_kernels\nfrom .._validation import x\n", False),
        "softpvtol_gym.envs.step": ("from ..control import kernels\nfrom .. import model\n", False),
    }
    upward, private, _ = check({**SOURCES, **ok})
    assert upward == [] and private == []


def test_the_documented_layers_are_the_checked_ones():
    """docs/getting-started.md's table of layers lists exactly LAYERS (layer numbers and module names)."""
    text = (ROOT / "docs" / "getting-started.md").read_text(encoding="utf-8")
    start = text.index("<!-- layers: start")
    rows = [line for line in text[start:text.index("<!-- layers: end -->")].splitlines() if line.startswith("| ")]
    documented = []
    for row in rows[1:]:  # after the header row
        cells = [c.strip() for c in row.strip("|").split("|")]
        names = tuple(n.strip("`") for n in cells[1].split(", ") if n.startswith("`"))
        documented.append((int(cells[0]), names + (("",) if "the package's `__init__`" in cells[1] else ())))
    assert documented == [(layer, tuple(prefixes)) for layer, prefixes in LAYERS]
