"""No module of sgloc keeps state between calls keyed by object identity (state a later call
reuses is held by an object the caller sees: a PreparedMap, a PreparedGraph), so a result
does not depend on what ran before: localizing A then B gives B's result bit for bit."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np

import sgloc
from sgloc import SemanticGraph, localize

SRC = Path(__file__).resolve().parents[1] / "src" / "sgloc"
_WEAK = {"WeakKeyDictionary", "WeakValueDictionary"}


def _called(node: ast.AST) -> str:
    """The called name of a call (`f(...)` or `a.f(...)`), else ''."""
    if isinstance(node, ast.Call):
        f = node.func
        return f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
    return ""


def _has_id_call(node: ast.AST, id_names: set[str]) -> bool:
    """Whether `node` holds a call of `id(...)` or a name assigned from one."""
    return any(_called(n) == "id" or (isinstance(n, ast.Name) and n.id in id_names)
               for n in ast.walk(node))  # fmt: skip


def identity_keyed_caches(tree: ast.Module) -> list[str]:
    """Module-level names of a module's identity-keyed caches: a WeakKeyDictionary or
    WeakValueDictionary, or a dict (`{}` / `dict()`) the module indexes, reads, fills or
    tests with a key built from `id(...)` (directly or through a name assigned from it)."""
    dicts, found = set(), []
    for node in tree.body:
        target, value = None, None
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            target, value = node.targets[0], node.value
        elif isinstance(node, ast.AnnAssign) and node.value is not None:
            target, value = node.target, node.value
        if not isinstance(target, ast.Name):
            continue
        if _called(value) in _WEAK:
            found.append(target.id)
        elif isinstance(value, ast.Dict) or _called(value) == "dict":
            dicts.add(target.id)
    id_names = {t.id for n in ast.walk(tree) if isinstance(n, ast.Assign)
                for t in n.targets if isinstance(t, ast.Name) and _has_id_call(n.value, set())}
    for n in ast.walk(tree):
        keys: list[ast.AST] = []
        if isinstance(n, ast.Subscript) and isinstance(n.value, ast.Name) and n.value.id in dicts:
            keys, name = [n.slice], n.value.id
        elif (isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute)
              and isinstance(n.func.value, ast.Name) and n.func.value.id in dicts and n.args):
            keys, name = [n.args[0]], n.func.value.id  # get / setdefault / pop
        elif (isinstance(n, ast.Compare) and len(n.comparators) == 1
              and isinstance(n.comparators[0], ast.Name) and n.comparators[0].id in dicts
              and isinstance(n.ops[0], ast.In | ast.NotIn)):
            keys, name = [n.left], n.comparators[0].id
        if any(_has_id_call(k, id_names) for k in keys) and name not in found:
            found.append(name)
    return found


def all_identity_keyed_caches(root: Path = SRC) -> list[str]:
    """'module: NAME' of every identity-keyed module-level cache under `root`."""
    out = []
    for path in sorted(root.rglob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        out += [f"{path.relative_to(root.parent)}: {name}" for name in identity_keyed_caches(tree)]
    return out


def test_scan_finds_the_patterns():
    """The scan sees each pattern it looks for (so an empty result means something)."""
    code = """
import weakref
A = weakref.WeakKeyDictionary()
B: dict[int, tuple] = {}
C = {}
D = {}
E = {}
def f(x):
    B[id(x)] = x
    key = id(x)
    C.setdefault(key, 1)
    D["name"] = x
    return id(x) in E
"""
    assert sorted(identity_keyed_caches(ast.parse(code))) == ["A", "B", "C", "E"]


def test_no_module_holds_an_identity_keyed_cache():
    found = all_identity_keyed_caches()
    assert not found, f"module-level caches keyed by object identity: {found}"


def _copy(g: SemanticGraph) -> SemanticGraph:
    return SemanticGraph(g.positions.copy(), g.labels.copy(), g.edge_radius, g.name)


def _same(a, b) -> None:
    assert a.accepted == b.accepted and a.reason == b.reason
    assert (a.transform is None) == (b.transform is None)
    if a.transform is not None:
        assert np.array_equal(a.transform, b.transform)  # bit for bit
    for name in ("matches", "candidates", "survivors", "scores"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.confidence == b.confidence


def test_a_then_b_equals_b_alone(airsim_graphs):
    """B's result after A ran on the same graph objects (and on a prepared map) equals B's on
    new objects made from copies of the arrays, bit for bit."""
    q, t = airsim_graphs
    rng = np.random.default_rng(7)
    part = q.subgraph(np.flatnonzero(np.linalg.norm(q.positions - q.positions[0], axis=1) < 150))
    localize(q, t, seed=1)  # A
    localize(t, q, seed=3)  # A, roles swapped
    after = localize(part, t, seed=5)  # B
    alone = localize(_copy(part), _copy(t), seed=5)
    _same(after, alone)
    assert after.accepted
    prepared = sgloc.prepare(t)
    localize(q, prepared, seed=1)  # A against the prepared map
    shifted = SemanticGraph(part.positions + rng.normal(0, 0.1, part.positions.shape),
                            part.labels, part.edge_radius)  # fmt: skip
    _same(localize(shifted, prepared, seed=5), localize(_copy(shifted), _copy(t), seed=5))
