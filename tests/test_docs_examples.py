"""Every ```python example of README.md and docs/*.md runs.

Each fenced ``python`` block runs on its own, in a fresh namespace, in a temporary working
directory (examples that write ``runs/...`` write there). A block may opt out with an HTML
comment on the line right above its fence, which MkDocs and GitHub do not show:

* ``<!-- docs-test: slow (REASON) -->``: runs only with ``-m slow`` (it simulates or trains
  for longer than the default suite allows);
* ``<!-- docs-test: skip (REASON) -->``: never runs here (it needs an NVIDIA GPU or a Ray
  cluster); the reason is the skip message.

A marker anywhere else, or one without a reason, fails the collection test below, so an
opt-out cannot drift away from its block.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import NamedTuple

import pytest

ROOT = Path(__file__).resolve().parents[1]
FILES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
MARKER = re.compile(r"^<!-- docs-test: (slow|skip) \((.+)\) -->$")
FENCE = re.compile(r"^```(\w*)\s*$")


class Example(NamedTuple):
    path: Path
    line: int  # 1-based line of the opening fence
    source: str
    mode: str  # "run", "slow" or "skip"
    reason: str


def _examples(path: Path) -> tuple[list[Example], list[str]]:
    """The python blocks of one file, and what is wrong with its markers."""
    lines = path.read_text().splitlines()
    found, problems = [], []
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            if "docs-test:" in lines[i] and not MARKER.match(lines[i].strip()):
                problems.append(f"{path.name}:{i + 1}: malformed marker {lines[i]!r}")
            i += 1
            continue
        start, lang = i, m.group(1)
        i += 1
        while i < len(lines) and not lines[i].startswith("```"):
            i += 1
        body = "\n".join(lines[start + 1:i]) + "\n"
        marker = MARKER.match(lines[start - 1].strip()) if start else None
        if lang == "python":
            mode, reason = (marker.group(1), marker.group(2)) if marker else ("run", "")
            found.append(Example(path, start + 1, body, mode, reason))
        elif marker:
            problems.append(f"{path.name}:{start}: a docs-test marker above a {lang or 'plain'} "
                            "block")
        i += 1
    for n, text in enumerate(lines):
        if MARKER.match(text.strip()) and not (n + 1 < len(lines)
                                               and lines[n + 1].startswith("```")):
            problems.append(f"{path.name}:{n + 1}: marker not right above a fence")
    return found, problems


EXAMPLES = [e for path in FILES for e in _examples(path)[0]]


def _param(example: Example):
    marks = [pytest.mark.slow] if example.mode == "slow" else []
    return pytest.param(example, marks=marks,
                        id=f"{example.path.relative_to(ROOT)}:{example.line}")


def test_examples_are_found_and_markers_are_well_formed():
    problems = [p for path in FILES for p in _examples(path)[1]]
    assert not problems, problems
    by_file = {e.path.name for e in EXAMPLES}
    # the README's API tour and the extension guide are examples, not prose
    assert {"README.md", "EXTENDING.md"} <= by_file, by_file
    assert sum(e.mode == "run" for e in EXAMPLES) >= 8


def test_the_extractor_sees_markers_and_fences(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("text\n\n<!-- docs-test: skip (needs a GPU) -->\n```python\nx = 1\n```\n"
                    "```python\ny = 2\n```\n<!-- docs-test: slow -->\n\n"
                    "<!-- docs-test: slow (long) -->\n```bash\nls\n```\n")
    found, problems = _examples(page)
    assert [(e.line, e.mode, e.reason) for e in found] == [(4, "skip", "needs a GPU"),
                                                          (7, "run", "")]
    # the marker without a reason; the one above a bash block
    assert len(problems) == 2, problems


@pytest.mark.parametrize("example", [_param(e) for e in EXAMPLES])
def test_example_runs(example: Example, tmp_path, monkeypatch):
    if example.mode == "skip":
        pytest.skip(example.reason)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    code = compile(example.source, f"{example.path.relative_to(ROOT)}:{example.line}", "exec")
    namespace = {"__name__": "__docs_example__"}
    exec(code, namespace)  # noqa: S102 - the documented code is what is under test
