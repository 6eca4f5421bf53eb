"""A wheel install in a fresh virtual environment, next to a project with top-level ``models``
and ``tools`` packages.

The wheel is built from a copy of the working tree (``pip wheel``, as ``pip install .`` would).
The fresh environment has no system site-packages and no PYTHONPATH; hmpc's dependencies come
from this checkout's ``.venv`` through a ``.pth`` line written after the installs (no network
beyond the build backend, and pip never sees the editable hmpc). Runs in ``make test``, about
25 s.
"""

from __future__ import annotations

import json
import os
import shutil
import site
import subprocess
import sys
import textwrap
import venv
from pathlib import Path

import pytest

from _data import REPO_DIR

SKIP_DIRS = {
    ".venv",
    ".git",
    "out",
    "build",
    "dist",
    "__pycache__",
    ".pytest_cache",
    ".hypothesis",
    "hmpc.egg-info",
}


def _run(cmd, cwd, timeout=300):
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["PYTHONNOUSERSITE"] = "1"
    return subprocess.run(
        [str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )


def _copy_tree(dst: Path) -> None:
    shutil.copytree(
        REPO_DIR,
        dst,
        ignore=lambda d, names: [n for n in names if n in SKIP_DIRS or n.endswith(".egg-info")],
    )


OTHER_PYPROJECT = """\
[build-system]
requires = ["setuptools>=61"]
build-backend = "setuptools.build_meta"

[project]
name = "someone-elses-research-code"
version = "1.0"

[tool.setuptools]
packages = ["models", "tools"]
"""


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(python of the fresh venv, its site-packages, a neutral working directory)."""
    tmp = tmp_path_factory.mktemp("install")
    src, other, wheels = tmp / "src", tmp / "other", tmp / "wheels"
    _copy_tree(src)
    for pkg in ("models", "tools"):
        (other / pkg).mkdir(parents=True)
        (other / pkg / "__init__.py").write_text(f'WHO = "someone else\'s {pkg}"\n')
    (other / "pyproject.toml").write_text(OTHER_PYPROJECT)
    build = _run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", wheels, src, other], cwd=tmp
    )
    if build.returncode and any(
        s in build.stderr
        for s in ("No matching distribution", "Could not find a version", "NewConnectionError")
    ):
        pytest.skip(f"the build backend could not be fetched (offline?): {build.stderr[-300:]}")
    assert build.returncode == 0, build.stderr[-3000:]
    whls = sorted(wheels.glob("*.whl"))
    assert len(whls) == 2, whls

    env_dir = tmp / "venv"
    venv.EnvBuilder(with_pip=False, system_site_packages=False, clear=True).create(env_dir)
    py = env_dir / "bin" / "python"
    inst = _run(
        [sys.executable, "-m", "pip", "--python", py, "install", "--no-deps", "-q", *whls], cwd=tmp
    )
    assert inst.returncode == 0, inst.stderr[-3000:]
    purelib = Path(
        _run(
            [py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], cwd=tmp
        ).stdout.strip()
    )
    # hmpc's dependencies, from this checkout's environment: a path line only (the .pth files
    # in that directory, among them the editable hmpc's finder, are not processed)
    (purelib / "zz_hmpc_test_deps.pth").write_text(site.getsitepackages()[0] + "\n")
    neutral = tmp / "elsewhere"
    neutral.mkdir()
    return py, purelib, neutral


def _packages_in_tree() -> list[str]:
    return sorted(
        "hmpc." + ".".join(p.parent.relative_to(REPO_DIR).parts)
        for d in ("models", "controller", "tools")
        for p in (REPO_DIR / d).rglob("__init__.py")
    )


CHECK = textwrap.dedent("""
    import importlib, json, sys
    import hmpc, models, tools
    import hmpc.models.logs.ingest, hmpc.controller.mpc, hmpc.tools.cli
    from hmpc.models.params import load_params
    from hmpc.tools import datafiles
    out = {"hmpc": hmpc.__file__, "models": models.__file__, "tools": tools.__file__,
           "models_who": models.WHO, "tools_who": tools.WHO, "version": hmpc.__version__,
           "path": sys.path, "missing": []}
    for name in json.loads(sys.argv[1]):
        try:
            importlib.import_module(name)
        except ImportError as exc:
            out["missing"].append(f"{name}: {exc}")
    out["params_dir"] = str(datafiles.PARAMS_DIR)
    out["data_dir"] = str(datafiles.DATA_DIR)
    p = load_params(datafiles.PARAMS_DIR / "report_2008.yaml", require_model=True)
    out["wheelbase_m"] = p.vehicle.wheelbase_m
    print(json.dumps(out))
""")


def test_wheel_imports_hmpc_and_leaves_the_other_projects_names_alone(installed):
    py, purelib, neutral = installed
    res = _run([py, "-c", CHECK, json.dumps(_packages_in_tree())], cwd=neutral)
    assert res.returncode == 0, res.stderr[-3000:]
    out = json.loads(res.stdout)
    # hmpc from the wheel's site-packages, never from the repository
    assert Path(out["hmpc"]).parent == purelib / "hmpc"
    assert not any(str(REPO_DIR) == p.rstrip("/") for p in out["path"])
    # the other project's top-level names are its own
    assert Path(out["models"]) == purelib / "models" / "__init__.py"
    assert Path(out["tools"]) == purelib / "tools" / "__init__.py"
    assert out["models_who"] == "someone else's models"
    assert out["tools_who"] == "someone else's tools"
    # every sub-package of the tree is in the wheel
    assert out["missing"] == [], "not in the wheel (pyproject.toml packages):\n" + "\n".join(
        out["missing"]
    )
    # parameter YAML and the bundled data are found inside the installed package
    assert Path(out["params_dir"]) == purelib / "hmpc" / "params"
    assert Path(out["data_dir"]) == purelib / "hmpc" / "tools" / "data"
    assert out["wheelbase_m"] > 0


def test_wheel_ships_every_params_and_data_file(installed):
    _, purelib, _ = installed
    for folder in ("params", "tools/data"):
        want = {
            p.relative_to(REPO_DIR / folder)
            for p in (REPO_DIR / folder).rglob("*")
            if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".py"
        }
        have = {
            p.relative_to(purelib / "hmpc" / folder)
            for p in (purelib / "hmpc" / folder).rglob("*")
            if p.is_file()
        }
        assert want <= have, f"{folder}/ files not in the wheel: {sorted(map(str, want - have))}"


def test_console_script_and_python_m_hmpc(installed, tmp_path):
    py, purelib, neutral = installed
    for cmd in ([py, "-m", "hmpc", "--version"], [py.parent / "hmpc", "--version"]):
        res = _run(cmd, cwd=neutral)
        assert res.returncode == 0, res.stderr[-2000:]
        assert res.stdout.strip() == "hmpc 0.1.0"
    # a real run on the installed bundled data
    data = purelib / "hmpc" / "tools" / "data"
    js = tmp_path / "info.json"
    res = _run(
        [
            py.parent / "hmpc",
            "info",
            data / "rav4-comma2k19" / "can.log.gz",
            "--dbc",
            data / "dbc" / "toyota_rav4_2017.dbc.gz",
            "--json",
            js,
        ],
        cwd=neutral,
    )
    assert res.returncode == 0, res.stderr[-2000:]
    info = json.loads(js.read_text())
    assert 59.0 < info["duration_s"] < 61.0
