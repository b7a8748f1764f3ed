"""Packaging and the import graph of the commands.

* installing sern_jax adds only ``sern_jax`` to the top-level import namespace: the script
  folders install as ``sern_jax.experiments``, ``sern_jax.figures``, ``sern_jax.proofs_check``;
* the build's package list is the package folders that exist (a new subpackage that is not
  listed would be missing from the wheel);
* no library module imports a command module (``sern_jax/commands/`` sits on top).

The wheel itself (build, install into a fresh venv outside the clone, smoke test from another
directory) is ``tests/test_wheel.py``, marked ``wheel``.
"""

import ast
import importlib.metadata
import os
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT_FOLDERS = ("experiments", "figures", "proofs_check")


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_build_lists_every_package_folder_under_sern_jax():
    tool = _pyproject()["tool"]["setuptools"]
    listed = set(tool["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts)
             for p in (ROOT / "sern_jax").rglob("__init__.py")
             if "__pycache__" not in p.parts}
    found |= {f"sern_jax.{f}" for f in SCRIPT_FOLDERS}
    assert listed == found, ("pyproject.toml [tool.setuptools] packages must list exactly the "
                             f"package folders: missing {sorted(found - listed)}, "
                             f"extra {sorted(listed - found)}")
    assert all(p == "sern_jax" or p.startswith("sern_jax.") for p in listed)
    assert tool["package-dir"] == {f"sern_jax.{f}": f for f in SCRIPT_FOLDERS}


def test_installed_distribution_adds_only_sern_jax_to_the_namespace():
    dist = importlib.metadata.distribution("sern_jax")
    assert (dist.read_text("top_level.txt") or "").split() == ["sern_jax"]
    owners = {name for name, dists in importlib.metadata.packages_distributions().items()
              if "sern_jax" in dists}
    assert owners == {"sern_jax"}, owners


def test_outside_the_clone_only_sern_jax_imports():
    # From a directory outside the clone the installed package (editable here, a wheel in
    # tests/test_wheel.py) resolves sern_jax.experiments etc. and no top-level script folder.
    script = textwrap.dedent("""
        import importlib.util, sys
        for folder in ("experiments", "figures", "proofs_check"):
            assert importlib.util.find_spec(folder) is None, folder + " is importable"
            spec = importlib.util.find_spec("sern_jax." + folder)
            assert spec is not None, "sern_jax." + folder
        import sern_jax.proofs_check.registry as r
        assert r.get("t2_exact_binomial").name == "t2_exact_binomial"
        from sern_jax.commands import scripts
        assert scripts.script_package("experiments").__name__ == "sern_jax.experiments"
        assert "grasp_learning" in scripts.experiment_names()
    """)
    env = dict(os.environ)
    # an install by PYTHONPATH (pip --target) stays; the clone itself must not be on the path
    keep = [p for p in env.get("PYTHONPATH", "").split(os.pathsep)
            if p and Path(p).resolve() != ROOT]
    env["PYTHONPATH"] = os.pathsep.join(keep)
    res = subprocess.run([sys.executable, "-c", script], cwd=ROOT.parent, env=env,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]


def _imported_names(path: Path) -> set[str]:
    """Every module a file imports at any depth, plus string literals naming sern_jax modules
    (importlib.import_module("sern_jax.commands...") counts)."""
    tree = ast.parse(path.read_text())
    parts = path.relative_to(ROOT).with_suffix("").parts
    package = parts[:-1]
    if package and package[0] in SCRIPT_FOLDERS:  # installed as sern_jax.<folder>
        package = ("sern_jax", *package)
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: resolve against the file's package
                base = ".".join(package[:len(package) - node.level + 1] + ((base,) if base else ()))
            names.add(base)
            names.update(f"{base}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) \
                and node.value.startswith("sern_jax."):
            names.add(node.value)
    return names


def test_no_library_module_imports_a_command_module():
    library = [p for p in (ROOT / "sern_jax").rglob("*.py")
               if "commands" not in p.relative_to(ROOT).parts and "__pycache__" not in p.parts]
    assert len(library) > 20
    offenders = {str(p.relative_to(ROOT)): sorted(n for n in _imported_names(p)
                                                  if n.startswith("sern_jax.commands"))
                 for p in library}
    offenders = {k: v for k, v in offenders.items() if v}
    assert not offenders, f"library modules import command modules: {offenders}"


def test_only_command_modules_import_the_script_folders():
    library = [p for p in (ROOT / "sern_jax").rglob("*.py")
               if "commands" not in p.relative_to(ROOT).parts and "__pycache__" not in p.parts]
    for p in library:
        tops = {n.split(".")[0] for n in _imported_names(p)}
        subs = {n.split(".")[1] for n in _imported_names(p)
                if n.startswith("sern_jax.") and n.count(".") >= 1}
        assert not tops & set(SCRIPT_FOLDERS), p
        assert not subs & set(SCRIPT_FOLDERS), p


def test_script_folders_import_each_other_only_through_sern_jax_or_relative():
    # ``from proofs_check import x`` inside proofs_check works from a clone but not installed
    # (there it is sern_jax.proofs_check): intra-folder imports are relative.
    for folder in SCRIPT_FOLDERS:
        for p in (ROOT / folder).glob("*.py"):
            tops = {n.split(".")[0] for n in _imported_names(p)}
            assert not tops & set(SCRIPT_FOLDERS), (p, tops & set(SCRIPT_FOLDERS))


def test_sern_experiment_lists_runs_and_refuses(capsys):
    from sern_jax.commands import main as cli

    assert cli.main(["experiment", "--list"]) == 0
    listed = capsys.readouterr().out.split()
    assert {"grasp_learning", "hard_objects"} <= set(listed)
    assert "regret" not in listed  # the regret experiment is library code: sern regret
    assert cli.main(["experiment", "no_such_experiment"]) == 2
    assert "unknown experiment" in capsys.readouterr().err
    with __import__("pytest").raises(SystemExit) as exc:  # the experiment's own --help
        cli.main(["experiment", "hard_objects", "--help"])
    assert exc.value.code == 0
    assert "sern experiment hard_objects" in capsys.readouterr().out
