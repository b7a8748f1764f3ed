"""The repository speaks of the project alone: no words about how it was made (team roles,
units of work, the machinery that provided a GPU) in any tracked text file, path or test
name. The phrases are written in pieces here, so that this file does not hold them whole."""

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

WORDS = re.compile(
    r"\bthe lead\b|\blead's\b|\bengineers?\b|\bhelper-\d+|\breviewer( \d)?\b|"
    r"\bdevice (tool|call|calls|time|allowance|machine)\b|`dev" r"ice`|\bdiag_" r"lead\b|"
    r"\bdiag_" r"g\b|"
    r"\b(this|that|next|later|earlier|previous|first|second|third|fourth|fifth|sixth) "
    r"session\b|\bsessions?\b(?= (of work|closing|note))|\bissues? #?\d+\b|\bthe issue('s)?\b|"
    r"\blent\b|\blease\b|\bwork units?\b",
    re.I)
TEXT = (".md", ".txt", ".py", ".sh", ".json", ".yml", ".yaml", ".toml", ".cff", ".cfg")


def _tracked() -> list[str]:
    try:
        out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                             check=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError):
        pytest.skip("not a git checkout")
    return [f for f in out.splitlines() if (ROOT / f).is_file()]


def offending_lines(text: str) -> list[str]:
    return [line.strip()[:120] for line in text.splitlines() if WORDS.search(line)]


def test_no_process_words_in_tracked_files():
    hits = {}
    for f in _tracked():
        if WORDS.search(f):
            hits[f] = ["(the path itself)"]
        if f.endswith(TEXT) and f != "tests/test_repository_words.py":
            try:
                lines = offending_lines((ROOT / f).read_text(encoding="utf-8"))
            except UnicodeDecodeError:
                continue
            if lines:
                hits.setdefault(f, []).extend(lines)
    assert not hits, "\n".join(f"{f}: {ls[:3]}" for f, ls in sorted(hits.items()))


def test_the_word_list_catches_what_it_names():
    # control: each kind of phrase is found, and the project's own words are not
    for bad in ("the le" "ad re-ran it", "engin" "eer G's change", "help" "er-45 found",
                "measured in the fifth sess" "ion", "iss" "ue 20 asks", "a dev" "ice call",
                "the le" "nt machine", "results/strong/diag_" "lead/"):
        assert offending_lines(bad), bad
    for fine in ("the leading term", "a lead-in", "an engineering tolerance",
                 "the H100 device", "leased", "reissue 20 draws"):
        assert not offending_lines(fine), fine
