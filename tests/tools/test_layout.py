"""The layout's rules (docs/style.md "Layout"), checked on the source.

- Imports flow one way, ``tools -> controller -> models``: nothing under models/ imports
  ``hmpc.controller`` or ``hmpc.tools``, nothing under controller/ imports ``hmpc.tools``;
  absolute (``hmpc.``) and relative (``from ..``) imports alike, anywhere in a module (also
  inside functions).
- No module imports generic top-level names (``models``, ``controller``, ``tools``),
  which would find another project's package of that name.
- Every package's ``__init__.py`` says in a docstring of at least two lines what lives there
  and what it may import.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from _data import REPO_DIR

FOLDERS = ("models", "controller", "tools")
#: stage -> the hmpc stages it must not import
FORBIDDEN = {
    "models": ("hmpc.controller", "hmpc.tools"),
    "controller": ("hmpc.tools",),
    "tools": (),
}
GENERIC = {"models", "controller", "tools"}


def _sources() -> list[Path]:
    files = sorted(
        p
        for d in FOLDERS
        for p in (REPO_DIR / d).rglob("*.py")
        if "data" not in p.relative_to(REPO_DIR).parts
    )
    assert len(files) > 40, "the source tree was not found"
    return files


def _module_name(path: Path) -> tuple[str, bool]:
    """Dotted name of ``path`` inside hmpc, and whether it is a package (__init__)."""
    parts = list(path.relative_to(REPO_DIR).with_suffix("").parts)
    is_pkg = parts[-1] == "__init__"
    if is_pkg:
        parts = parts[:-1]
    return ".".join(["hmpc", *parts]), is_pkg


def imports_of(path: Path, text: str | None = None) -> list[tuple[int, str]]:
    """Every module ``path`` imports, absolute, with its line: relative imports resolved.

    ``text``: the source to parse as if it were ``path`` (default: the file's own text).
    """
    name, is_pkg = _module_name(path)
    package = name if is_pkg else name.rsplit(".", 1)[0]
    out = []
    for node in ast.walk(
        ast.parse(path.read_text(encoding="utf-8") if text is None else text, filename=str(path))
    ):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                if node.level - 1 >= len(base):
                    raise AssertionError(f"{path}:{node.lineno}: relative import beyond hmpc")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.append((node.lineno, mod))
            # ``from hmpc import tools`` / ``from .. import controller`` import a sub-package
            out += [(node.lineno, f"{mod}.{a.name}") for a in node.names if a.name != "*"]
    return out


def _is_under(mod: str, pkg: str) -> bool:
    return mod == pkg or mod.startswith(pkg + ".")


def test_the_check_can_fail():
    """A planted forbidden import is found, in both spellings and inside a function."""
    probe = REPO_DIR / "models" / "logs" / "_layout_probe.py"  # never written: parsed as if
    src = (
        "from ...controller import mpc\nimport hmpc.tools.cli\n"
        "def f():\n    from ..plant import HybridPlant\n    from ... import tools\n"
    )
    found = [m for _, m in imports_of(probe, src)]
    assert "hmpc.controller.mpc" in found and "hmpc.tools.cli" in found
    assert "hmpc.models.plant.HybridPlant" in found and "hmpc.tools" in found


@pytest.mark.parametrize("stage", FOLDERS)
def test_imports_flow_tools_controller_models(stage):
    bad = []
    for path in _sources():
        if path.relative_to(REPO_DIR).parts[0] != stage:
            continue
        for line, mod in imports_of(path):
            for pkg in FORBIDDEN[stage]:
                if _is_under(mod, pkg):
                    bad.append(f"{path.relative_to(REPO_DIR)}:{line}: imports {mod}")
    assert not bad, f"{stage}/ must not import {FORBIDDEN[stage]}:\n" + "\n".join(bad)


def test_no_generic_top_level_imports():
    bad = [
        f"{p.relative_to(REPO_DIR)}:{line}: imports {mod}"
        for p in [*_sources(), *sorted((REPO_DIR / "tests").rglob("*.py"))]
        for line, mod in imports_of(p)
        if mod.split(".")[0] in GENERIC
    ]
    assert not bad, "import hmpc.models/controller/tools, never the bare name:\n" + "\n".join(bad)


def _packages() -> list[Path]:
    dirs = {p.parent for p in _sources()}
    return sorted([REPO_DIR / "__init__.py", *(d / "__init__.py" for d in dirs)])


@pytest.mark.parametrize("init", _packages(), ids=lambda p: str(p.relative_to(REPO_DIR)))
def test_every_package_says_what_lives_there_and_what_it_may_import(init):
    assert init.is_file(), f"{init.parent.relative_to(REPO_DIR)}/ has .py files but no __init__.py"
    doc = ast.get_docstring(ast.parse(init.read_text(encoding="utf-8")))
    assert doc, f"{init.relative_to(REPO_DIR)}: no docstring"
    lines = [ln for ln in doc.splitlines() if ln.strip()]
    assert len(lines) >= 2 and len(doc.split()) >= 10, f"{init}: say what lives here"
    assert "import" in doc.lower(), f"{init.relative_to(REPO_DIR)}: say what it may import"


def test_architecture_doc_names_every_package_and_module():
    """docs/architecture.md matches the tree: every package folder appears as a path, and
    every module of a package appears in that package's row of its Layout table."""
    arch = (REPO_DIR / "docs" / "architecture.md").read_text(encoding="utf-8")
    layout = arch[arch.index("## Layout") :]
    end = layout.find("\n## ")  # the Layout section ends at the next heading
    if end != -1:
        layout = layout[:end]
    rows = {}
    for line in layout.splitlines():
        if line.startswith("| `") and line.count("|") >= 3:
            folder, holds = line.split("|")[1:3]
            rows[folder.strip().strip("`").rstrip("/")] = holds
    missing = []
    for init in _packages():
        folder = str(init.parent.relative_to(REPO_DIR))
        if folder == ".":
            continue
        if f"`{folder}/`" not in arch:
            missing.append(f"{folder}/ (no row, not in the architecture)")
            continue
        for mod in sorted(init.parent.glob("*.py")):
            if (
                mod.stem != "__init__"
                and f"`{mod.stem}`" not in rows.get(folder, "")
                and not (folder == "tools" and mod.stem.startswith(("cmd_", "bench_")))
            ):
                missing.append(f"{folder}/{mod.name}")
    assert not missing, "docs/architecture.md's Layout does not name:\n" + "\n".join(missing)
