"""The README's links resolve, and the citation and license files match the package."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _slug(heading: str) -> str:
    """The id MkDocs' toc extension (and GitHub) gives a heading, for the headings we use."""
    text = re.sub(r"[`*]", "", heading).strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return re.sub(r"[\s]+", "-", text)


def _anchors(path: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    return {_slug(m.group(1)) for m in re.finditer(r"^#{1,6} (.+)$", text, flags=re.M)}


def _links(path: Path):
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    return [m.group(1) for m in LINK.finditer(text)]


def test_readme_fits_and_its_links_resolve():
    readme = ROOT / "README.md"
    assert len(readme.read_text()) <= 12_000
    broken = []
    for link in _links(readme):
        if link.startswith(("http://", "https://")):
            continue
        target, _, anchor = link.partition("#")
        path = ROOT / target if target else readme
        if not path.exists():
            broken.append(link)
        elif anchor and anchor not in _anchors(path):
            broken.append(link)
    assert not broken, broken


def test_slug_matches_the_docs_headings():
    assert _slug("Add a learner") == "add-a-learner"
    assert _slug("`sern grasp learn`") == "sern-grasp-learn"
    assert "add-a-learner" in _anchors(ROOT / "docs" / "EXTENDING.md")


def test_citation_and_license_match_the_package():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    cff = (ROOT / "CITATION.cff").read_text()  # YAML; its top-level keys read as lines
    top = dict(re.findall(r"^([a-z-]+): *(\S.*)$", cff, flags=re.M))
    assert top["cff-version"] == "1.2.0"
    assert top["version"] == project["version"]
    assert top["license"] == project["license"] == "Apache-2.0"
    assert re.search(r"^references:\n  - type: \w+\n    title: \"No-Regret Shannon Entropy", cff,
                     flags=re.M)
    license_text = (ROOT / "LICENSE").read_text()
    assert "Apache License" in license_text and "Version 2.0, January 2004" in license_text
    assert "END OF TERMS AND CONDITIONS" in license_text
