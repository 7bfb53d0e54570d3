"""The package's layering, read from the source with `ast` (module- and function-level imports,
TYPE_CHECKING ones too): data flows one way (graph -> descriptors -> matching -> rejection ->
RANSAC -> pose -> acceptance -> localizer -> fleet -> tools such as the replay -> evaluation ->
CLI; the file readers and writers sit above the maps they read), so no module imports a higher
layer, no two modules import each other (directly or round a loop), and no module (nor test)
imports another module's private (`_name`) names."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
TESTS = ROOT / "tests"

#: Layer rank of every module, by its dotted name or the longest listed prefix of it. A module
#: may import its own rank and lower ones only.
LAYERS: dict[str, int] = {
    # base: no pipeline stage
    "sgloc.errors": 0,
    "sgloc.optional": 0,
    "sgloc.validation": 0,
    "sgloc.registry": 0,
    "sgloc.geometry": 0,
    "sgloc.lie": 0,  # SO(3) / SE(3): skew, exp, log, adjoint
    "sgloc.kernels": 0,  # the compiled kernels' runtime (the kernels live beside their stages)
    "sgloc.runtime": 0,  # task runner, worker processes, stage timings
    # maps, then the files they are read from and written to (readers need the class tables)
    "sgloc.maps": 1,  # graph, association, canonical form, prepared graph, classes, scale
    "sgloc.io": 2,
    # matching
    "sgloc.descriptors": 3,
    "sgloc.matching": 3,
    "sgloc.consistency": 3,
    "sgloc.rejection": 4,
    "sgloc.estimation": 5,
    "sgloc.acceptance": 6,
    # the localizer and its settings
    "sgloc.pipeline": 7,  # config, presets, localize, prepared maps, register
    "sgloc": 8,  # the package's own __init__: the public API, up to the fleet
    # many maps
    "sgloc.online": 8,  # the online session, its back-ends, the batch fleet, map merging
    # tools around the library
    "sgloc.datasets": 9,
    "sgloc.extraction": 9,
    "sgloc.sim": 9,
    "sgloc.live": 9,  # the live server over Zenoh, its robot client and messages
    "sgloc.replay": 9,
    "sgloc.warmup": 9,
    # measuring the tools: the evaluation runs the replay on its runs with ground truth
    "sgloc.evaluation": 10,
    "sgloc.experiments": 10,  # the paper's experiments, checked and run (on evaluation)
    # the command line
    "sgloc.cli": 11,
    "sgloc.__main__": 11,
}


#: Imports that break the layering today, each with the change that removes it. Keep empty.
KNOWN: dict[tuple[str, str], str] = {}


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


SRC_MODULES: dict[str, Path] = {
    _module_name(p, SRC): p for p in sorted((SRC / "sgloc").rglob("*.py"))
}


def rank(module: str) -> int:
    """The layer of `module`: the entry of its longest listed prefix."""
    parts = module.split(".")
    for n in range(len(parts), 0, -1):
        key = ".".join(parts[:n])
        if key in LAYERS:
            return LAYERS[key]
    raise KeyError(module)


def _is_package(module: str) -> bool:
    return SRC_MODULES.get(module, Path()).name == "__init__.py"


def _imports(module: str, path: Path) -> Iterator[tuple[str, list[str], int]]:
    """(imported sgloc module, names taken from it, line) of every import in `path`."""
    tree = ast.parse(path.read_text(), filename=str(path))
    package = module if _is_package(module) else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "sgloc":
                    yield alias.name, [], node.lineno
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, base] if base else anchor)
            if base.split(".")[0] != "sgloc":
                continue
            names = []
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                if sub in SRC_MODULES:  # `from sgloc.x import submodule`
                    yield sub, [], node.lineno
                else:
                    names.append(alias.name)
            if names:
                yield base, names, node.lineno


def _edges() -> dict[str, set[str]]:
    """{module: the modules its imports run}: the imported module and the packages above it
    (their `__init__` runs first) other than the importer's own packages and `sgloc` itself."""
    graph: dict[str, set[str]] = {m: set() for m in SRC_MODULES}
    for module, path in SRC_MODULES.items():
        own = {module.rsplit(".", n)[0] for n in range(module.count(".") + 1)}
        for target, _, _ in _imports(module, path):
            parts = target.split(".")
            runs = {".".join(parts[:n]) for n in range(2, len(parts) + 1)}
            graph[module] |= {t for t in runs - own if t in SRC_MODULES}
    return graph


def test_every_module_has_a_layer():
    missing = []
    for m in SRC_MODULES:
        try:
            rank(m)
        except KeyError:
            missing.append(m)
    assert not missing, f"add these modules to LAYERS: {missing}"


def test_no_module_imports_a_higher_layer():
    bad = []
    for module, path in SRC_MODULES.items():
        for target, _, line in _imports(module, path):
            known = (module, target) in KNOWN
            if target in SRC_MODULES and rank(target) > rank(module) and not known:
                bad.append(f"{path.relative_to(ROOT)}:{line}: {module} ({rank(module)}) "
                           f"imports {target} ({rank(target)})")  # fmt: skip
    assert not bad, "\n".join(bad)


def test_the_evaluation_sits_above_the_replay_and_files_above_maps():
    # the replay must not need the evaluation (it runs the replay), nor a map its files
    assert rank("sgloc.replay.job") < rank("sgloc.evaluation.replay_scenarios")
    assert rank("sgloc.maps.graph") < rank("sgloc.io.graph_files")


def test_every_known_break_is_still_there():
    found = {(m, t) for m, p in SRC_MODULES.items() for t, _, _ in _imports(m, p)}
    stale = [pair for pair in KNOWN if pair not in found]
    assert not stale, f"these imports are gone: remove them from KNOWN: {stale}"


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle():
    graph = _edges()
    assert not _cycles(graph), _cycles(graph)


def test_the_cycle_finder_finds_a_loop():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _private_imports(files: dict[str, Path]) -> list[str]:
    """`from sgloc.x import _name` and `x._name` on an imported sgloc module `x`."""
    bad = []
    for module, path in files.items():
        for target, names, line in _imports(module, path):
            private = [n for n in names if _private(n)]
            if private and target != module:
                bad.append(f"{path.relative_to(ROOT)}:{line}: {', '.join(private)} from {target}")
        bound = set()
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom):
                mod = getattr(node, "module", None) or ""
                for alias in node.names:
                    full = alias.name if isinstance(node, ast.Import) else f"{mod}.{alias.name}"
                    if full.startswith("sgloc") and full in SRC_MODULES and full != module:
                        bound.add(alias.asname or alias.name.split(".")[0])
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and _private(node.attr)
                    and isinstance(node.value, ast.Name) and node.value.id in bound):  # fmt: skip
                bad.append(f"{path.relative_to(ROOT)}:{node.lineno}: {node.value.id}.{node.attr}")
    return bad


def test_no_module_imports_private_names():
    bad = _private_imports(SRC_MODULES)
    assert not bad, "\n".join(bad)


def test_no_test_imports_private_names():
    files = {f"tests.{p.stem}": p for p in sorted(TESTS.rglob("*.py"))}
    bad = _private_imports(files)
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize(
    ("module", "layer"),
    [("sgloc.estimation.fit_kernels", 5), ("sgloc.io.graph_files", 2),
     ("sgloc.acceptance.chance", 6), ("sgloc", 8), ("sgloc.cli.app", 11)],  # fmt: skip
)
def test_rank_reads_the_longest_prefix(module, layer):
    assert rank(module) == layer
