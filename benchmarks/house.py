"""The house plan's counts, read from the source with `ast`: loose top-level modules, module-level
caches keyed by object identity, stage modules that choose between a compiled kernel and a numpy
twin (`use_compiled` / `FORCE`) and those whose twin lives in another folder, stage modules
calling another package's kernel module, command functions over 40 lines, and the length of
docs/architecture.md. Usage: python benchmarks/house.py"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "src" / "sgloc"
CACHE_TYPES = {"dict", "WeakKeyDictionary", "WeakValueDictionary", "OrderedDict"}


def loose_modules() -> list[str]:
    """Top-level modules of the package other than `__init__` and `__main__`."""
    return sorted(p.stem for p in PKG.glob("*.py") if p.stem not in ("__init__", "__main__"))


def _module_dicts(tree: ast.Module, weak_only: bool = False) -> set[str]:
    """Names of module-level dicts (`weak_only`: weak-keyed or weak-valued ones)."""
    names = set()
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else (
            [node.target] if isinstance(node, ast.AnnAssign) and node.value else [])
        value = getattr(node, "value", None)
        empty = isinstance(value, ast.Dict) and not value.keys
        kind = getattr(value.func, "attr", getattr(value.func, "id", "")) if isinstance(
            value, ast.Call) else ""
        wanted = kind.startswith("Weak") if weak_only else (empty or kind in CACHE_TYPES)
        if wanted:
            names |= {t.id for t in targets if isinstance(t, ast.Name)}
    return names


def _uses_id(node: ast.AST) -> bool:
    return any(isinstance(n, ast.Call) and getattr(n.func, "id", "") == "id"
               for n in ast.walk(node))


def identity_caches() -> list[str]:
    """Module-level weak dictionaries (keyed by an object's identity), and module-level dicts
    indexed (or .get/.setdefault/.pop) with a key built from `id(...)`."""
    found = []
    for path in sorted(PKG.rglob("*.py")):
        tree = ast.parse(path.read_text())
        dicts = _module_dicts(tree)
        keyed = _module_dicts(tree, weak_only=True)
        for n in ast.walk(tree):
            if isinstance(n, ast.Subscript) and getattr(n.value, "id", None) in dicts:
                if _uses_id(n.slice) or _id_named(n.slice, tree):
                    keyed.add(n.value.id)
            if (isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute)
                    and getattr(n.func.value, "id", None) in dicts and n.args
                    and (_uses_id(n.args[0]) or _id_named(n.args[0], tree))):
                keyed.add(n.func.value.id)
        found += [f"{path.relative_to(PKG.parent)}:{name}" for name in sorted(keyed)]
    return found


def _id_named(node: ast.AST, tree: ast.Module) -> bool:
    """A key held in a local variable that was assigned from an expression with `id(...)`."""
    if not isinstance(node, ast.Name):
        return False
    return any(isinstance(a, ast.Assign) and any(getattr(t, "id", None) == node.id
                                                  for t in a.targets) and _uses_id(a.value)
               for a in ast.walk(tree))


def compiled_branches() -> list[str]:
    """Modules that choose between a compiled kernel and its numpy twin: a branch on
    `use_compiled`, or any use of `use_compiled` / `FORCE` (the switch between the two)."""
    out = []
    for path in sorted(PKG.rglob("*.py")):
        tree = ast.parse(path.read_text())
        branch = any(isinstance(n, ast.If) and "use_compiled" in ast.unparse(n.test)
                     for n in ast.walk(tree))
        switch = any(isinstance(n, ast.Name | ast.Attribute | ast.alias)
                     and {"use_compiled", "FORCE"} & {getattr(n, "id", None),
                                                      getattr(n, "attr", None),
                                                      getattr(n, "name", None)}
                     for n in ast.walk(tree))
        if branch or switch:
            out.append(str(path.relative_to(PKG.parent)))
    return out


def _kernel_imports(tree: ast.Module) -> set[str]:
    """Kernel modules (`*kernels` modules of a stage package) a module imports."""
    found = set()
    for n in ast.walk(tree):
        if isinstance(n, ast.ImportFrom) and n.module and n.module.startswith("sgloc."):
            found |= {n.module} if n.module.endswith("kernels") else {
                f"{n.module}.{a.name}" for a in n.names if a.name.endswith("kernels")}
    return found - {"sgloc.kernels"}


def kernels_elsewhere() -> list[str]:
    """Modules branching on `use_compiled` whose compiled twin lives in another folder."""
    out = []
    for name in compiled_branches():
        path = PKG.parent / name
        folder = ".".join(path.relative_to(PKG.parent).with_suffix("").parts[:-1])
        away = [k for k in _kernel_imports(ast.parse(path.read_text()))
                if k.rsplit(".", 1)[0] != folder]
        if away:
            out.append(f"{name} ({', '.join(sorted(away))})")
    return out


def foreign_kernels() -> list[str]:
    """Stage modules (outside `sgloc.kernels` and the kernel modules themselves) that call a
    kernel module of another package (a kernel shared by several stages)."""
    out = []
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG)
        if rel.parts[0] == "kernels" or path.stem.endswith("kernels"):
            continue
        folder = ".".join(("sgloc", *rel.parts[:-1]))
        away = [k for k in _kernel_imports(ast.parse(path.read_text()))
                if k.rsplit(".", 1)[0] != folder]
        if away:
            out.append(f"{path.relative_to(PKG.parent)} ({', '.join(sorted(away))})")
    return out


def long_commands(limit: int = 40) -> list[str]:
    """Functions of `sgloc.cli` longer than `limit` lines (decorators and docstring included)."""
    out = []
    for path in sorted((PKG / "cli").glob("*.py")):
        for n in ast.walk(ast.parse(path.read_text())):
            if isinstance(n, ast.FunctionDef):
                start = min([n.lineno, *(d.lineno for d in n.decorator_list)])
                if n.end_lineno - start + 1 > limit:
                    out.append(f"{path.name}:{n.name} ({n.end_lineno - start + 1} lines)")
    return out


def main() -> int:
    words = len((ROOT / "docs" / "architecture.md").read_text().split())
    rows = [
        ("loose top-level modules (goal <= 8)", loose_modules()),
        ("identity-keyed module caches (goal 0)", identity_caches()),
        ("stage modules whose compiled twin lives in another folder (goal 0)",
         kernels_elsewhere()),
        ("modules choosing between a kernel and a numpy twin (use_compiled / FORCE; goal 0)",
         compiled_branches()),
        ("stage modules calling another package's kernel module (shared kernels)",
         foreign_kernels()),
        ("command functions over 40 lines (goal 0)", long_commands()),
    ]
    print("| count | now | which |\n|---|---|---|")
    for name, items in rows:
        print(f"| {name} | {len(items)} | {', '.join(items)} |")
    print(f"| docs/architecture.md words (goal <= 1,500) | {words} | |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
