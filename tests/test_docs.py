"""Every shell command and Python snippet of README.md and docs/*.md runs as written.

Fenced blocks tagged bash/sh/shell/python are extracted in order and run, the blocks of one
file sharing one scratch folder (so a block may use what an earlier one wrote). An HTML comment
on the line(s) just before a fence tunes one block; clauses are separated by `;`:

    <!-- docs-test: skip REASON -->          not run here, with the reason (the rest of the
                                             comment, `;` included)
    <!-- docs-test: replace "OLD" "NEW" -->  run with OLD replaced (e.g. short trial counts)
    <!-- docs-test: data -->                 needs the downloaded KITTI 00 set
    <!-- docs-test: slow -->                 runs only with SGLOC_DOCS_SLOW=1 (CI sets it)
    <!-- docs-test: timeout 600 -->          seconds allowed (default 300)

`sgloc` and `python` inside shell blocks are this test's interpreter and package.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

import sgloc

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LANGS = {"bash": "bash", "sh": "bash", "shell": "bash", "python": "python", "py": "python"}
FENCE = re.compile(r"^```(\w+)?\s*$")
DIRECTIVE = re.compile(r"^<!--\s*docs-test:(.*?)-->\s*$")


@dataclass
class Snippet:
    doc: Path
    line: int
    lang: str
    code: str
    skip: str | None = None
    slow: bool = False
    data: bool = False
    timeout: float = 300.0
    replace: list[tuple[str, str]] = field(default_factory=list)
    error: str | None = None  # a malformed directive: reported by this block's test

    @property
    def id(self) -> str:
        return f"{self.doc.relative_to(ROOT)}:{self.line}"

    def runnable(self) -> str:
        code = self.code
        for old, new in self.replace:
            if old not in code:
                raise AssertionError(f"{self.id}: replace target {old!r} not in the block")
            code = code.replace(old, new)
        return code


def extract(doc: Path) -> list[Snippet]:
    """The runnable fenced blocks of a Markdown file, with their directives."""
    lines = doc.read_text().splitlines()
    out, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        j = i + 1
        while j < len(lines) and not lines[j].startswith("```"):
            j += 1
        lang = LANGS.get((m.group(1) or "").lower())
        if lang:
            s = Snippet(doc, i + 1, lang, "\n".join(lines[i + 1 : j]) + "\n")
            k = i - 1
            while k >= 0 and (DIRECTIVE.match(lines[k]) or not lines[k].strip()):
                d = DIRECTIVE.match(lines[k])
                if d:
                    _apply(s, d.group(1))
                k -= 1
            out.append(s)
        i = j + 1
    return out


def _apply(s: Snippet, text: str) -> None:
    if text.strip().startswith("skip"):
        s.skip = text.strip()[4:].strip() or "marked skip"
        return
    for clause in filter(None, (c.strip() for c in text.split(";"))):
        word, _, rest = clause.partition(" ")
        if word == "skip":
            s.skip = rest.strip() or "marked skip"
        elif word == "slow":
            s.slow = True
        elif word == "data":
            s.data = True
        elif word == "timeout":
            s.timeout = float(rest)
        elif word == "replace" and len(shlex.split(rest)) == 2:
            old, new = shlex.split(rest)
            s.replace.append((old, new))
        else:
            s.error = f"{s.id}: unknown or malformed docs-test directive {clause!r}"


SNIPPETS = [s for doc in DOCS for s in extract(doc)]


def _params():
    for s in SNIPPETS:
        marks = [pytest.mark.data] if s.data else []
        yield pytest.param(s, id=s.id, marks=marks)


@pytest.fixture(scope="session")
def doc_dirs(tmp_path_factory):
    """One scratch folder per Markdown file, shared by its blocks in order."""
    cache: dict[Path, Path] = {}

    def get(doc: Path) -> Path:
        if doc not in cache:
            cache[doc] = tmp_path_factory.mktemp(doc.stem)
        return cache[doc]

    return get


def _env() -> dict[str, str]:
    env = dict(os.environ)
    src = str(Path(sgloc.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [src, env.get("PYTHONPATH")]))
    env["SGLOC_PY"] = sys.executable
    env["MPLBACKEND"] = "Agg"
    env["COLUMNS"] = "120"
    return env


BASH_PRELUDE = """set -euo pipefail
sgloc() { "$SGLOC_PY" -m sgloc "$@"; }
python() { "$SGLOC_PY" "$@"; }
python3() { "$SGLOC_PY" "$@"; }
"""


def test_directives_parse_and_every_doc_has_been_read():
    assert any(s.doc.name == "README.md" for s in SNIPPETS)
    for s in SNIPPETS:
        s.runnable()  # every replace target is present


@pytest.mark.parametrize("snippet", list(_params()))
def test_snippet_runs(snippet: Snippet, doc_dirs):
    assert snippet.error is None, snippet.error
    if snippet.skip:
        pytest.skip(f"not run in tests: {snippet.skip}")
    if snippet.slow and os.environ.get("SGLOC_DOCS_SLOW", "") in ("", "0"):
        pytest.skip("slow; run with SGLOC_DOCS_SLOW=1")
    cwd = doc_dirs(snippet.doc)
    code = snippet.runnable()
    if snippet.lang == "bash":
        argv = ["bash", "-c", BASH_PRELUDE + code]
    else:
        path = cwd / f"snippet_{snippet.line}.py"
        path.write_text(code)
        argv = [sys.executable, str(path)]
    proc = subprocess.run(argv, cwd=cwd, env=_env(), capture_output=True, text=True,
                          timeout=snippet.timeout)
    assert proc.returncode == 0, (
        f"{snippet.id} failed (exit {proc.returncode}):\n{code}\n--- stdout\n"
        f"{proc.stdout[-3000:]}\n--- stderr\n{proc.stderr[-3000:]}"
    )


def test_no_merge_conflict_markers_left():
    """No text file of the repository holds a line a conflicted merge leaves behind."""
    root = ROOT
    files = [root / "README.md", root / "pyproject.toml"]
    for folder, patterns in (("docs", ("*.md",)), ("src", ("*.py", "*.json", "*.yaml")),
                             ("tests", ("*.py",)), ("benchmarks", ("*.py", "*.sh"))):  # fmt: skip
        files += [p for pattern in patterns for p in (root / folder).rglob(pattern)]
    marker = re.compile(r"^(<{7}|>{7}) |^={7}$", re.M)
    left = [str(p.relative_to(root)) for p in files if marker.search(p.read_text("utf-8"))]
    assert not left, f"merge conflict markers in {left}"
