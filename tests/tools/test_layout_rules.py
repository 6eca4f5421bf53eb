"""The layout's rules on what runs where, checked on the source (docs/architecture.md).

Each rule has a planted violation that its check must catch, so a check that cannot fail
shows up as a failing ``test_*_catches_a_planted_violation``.

- Code that runs on the car (controllers, estimator, limits, the drive loop, frame builders
  and safety, the tele-op link and vehicle side) never imports the simulator, not even
  through another module: only the closed-loop harness and the simulated car on the bus do.
- A reference path is a module of its own outside the simulator; building a controller from
  a parameter file is library code in ``controller/``.
- Subcommand modules never import each other (nor the CLI that imports them); what they
  share lives in ``tools/common.py``.
- Run metrics are their own module: the drive loop does not import the simulation harness.
- Plots live in ``models/report/``: nothing else imports matplotlib.
- No import circles between hmpc's modules (function-level imports count).
- No module over 800 lines; no issue numbers in code.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path


from _data import REPO_DIR
from test_layout import imports_of

FOLDERS = ("models", "controller", "tools")
SIM = "hmpc.models.sim"
#: controller modules that stand in for the car or drive it offline, and so may use the
#: simulator: the closed-loop harness, the simulated car on the bus, the offline replay (which
#: runs the closed-loop harness) and the tele-op plant stand-in
HARNESS = {
    "hmpc.controller.closed_loop",
    "hmpc.controller.actuation.vehicle_node",
    "hmpc.controller.replay",
    "hmpc.controller.teleop.sink",
    "hmpc.controller.teleop.selftest",
}
MAX_LINES = 800
ISSUE_RE = re.compile(r"\bissues?\s+#?\d+", re.IGNORECASE)


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO_DIR).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(["hmpc", *parts])


def _sources() -> dict[str, Path]:
    files = {
        _module_name(p): p
        for d in FOLDERS
        for p in sorted((REPO_DIR / d).rglob("*.py"))
        if "data" not in p.relative_to(REPO_DIR).parts
    }
    assert len(files) > 60, "the source tree was not found"
    return files


def _graph(sources: dict[str, Path], texts: dict[str, str] | None = None) -> dict[str, set[str]]:
    """module -> the hmpc modules it imports (``from pkg import name`` resolves to the module
    ``pkg.name`` when that is a module, else to ``pkg``); every import, at any depth."""
    texts = texts or {}
    out: dict[str, set[str]] = {}
    for mod, path in sources.items():
        deps = set()
        for _, name in imports_of(path, texts.get(mod)):
            while name and name not in sources:
                name = name.rpartition(".")[0]
            if name and name != mod and name.startswith("hmpc."):
                deps.add(name)
        out[mod] = deps
    return out


def _reaches(graph: dict[str, set[str]], start: str, target: str) -> list[str] | None:
    """An import chain from ``start`` to a module under ``target``, or None."""
    seen, stack = {start}, [(start, [start])]
    while stack:
        mod, chain = stack.pop()
        for dep in sorted(graph.get(mod, ())):
            if dep == target or dep.startswith(target + "."):
                return chain + [dep]
            if dep not in seen:
                seen.add(dep)
                stack.append((dep, chain + [dep]))
    return None


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on, stack, out = set(), [], []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _package_faces(graph: dict[str, set[str]], sources: dict[str, Path]) -> dict[str, set[str]]:
    """The graph without the edges a package's own ``__init__`` adds by re-exporting its
    members (a member importing a sibling through the package is not a circle of code)."""
    pkgs = {m for m, p in sources.items() if p.name == "__init__.py"}
    return {
        m: {d for d in deps if not (m in pkgs and d.startswith(m + "."))}
        for m, deps in graph.items()
    }


# ------------------------------------------------------------------------ the simulator
def _on_car(sources: dict[str, Path]) -> list[str]:
    return [
        m
        for m in sources
        if m.startswith("hmpc.controller.") and m not in HARNESS and not m.endswith(".__init__")
    ]


def _sim_chains(graph: dict[str, set[str]], modules: list[str]) -> list[str]:
    bad = []
    for mod in modules:
        chain = _reaches(graph, mod, SIM)
        if chain:
            bad.append(" -> ".join(chain))
    return bad


def test_code_on_the_car_never_reaches_the_simulator():
    sources = _sources()
    graph = _graph(sources)
    bad = _sim_chains(graph, _on_car(sources))
    assert not bad, "modules that run on the car import the simulator:\n" + "\n".join(bad)


def test_sim_rule_catches_a_planted_violation():
    """An on-car module that imports a harness module (which imports the simulator) inside a
    function is caught, as is a direct import."""
    sources = _sources()
    texts = {
        "hmpc.controller.limits": "def f():\n    from hmpc.controller import closed_loop\n",
        "hmpc.controller.pid": "import hmpc.models.sim.scenarios\n",
    }
    graph = _graph(sources, texts)
    bad = _sim_chains(graph, ["hmpc.controller.limits", "hmpc.controller.pid"])
    assert len(bad) == 2 and "hmpc.controller.closed_loop" in bad[0] + bad[1]


def test_the_harness_list_names_real_modules():
    sources = _sources()
    assert HARNESS <= set(sources), HARNESS - set(sources)


# ------------------------------------------------------------------------ where things live
def _defines(path: Path, name: str) -> bool:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return any(isinstance(n, (ast.ClassDef, ast.FunctionDef)) and n.name == name for n in tree.body)


def test_reference_and_controller_building_live_outside_sim_and_tools():
    sources = _sources()
    where = {
        n: [m for m, p in sources.items() if _defines(p, n)]
        for n in ("Reference", "make_controller", "load_reference")
    }
    assert where["Reference"] == ["hmpc.models.reference"], where
    assert where["load_reference"] == ["hmpc.models.reference"], where
    assert where["make_controller"] == ["hmpc.controller.build"], where


# ------------------------------------------------------------------------ subcommands
def _cmd_cross_imports(graph: dict[str, set[str]]) -> list[str]:
    cmds = [m for m in graph if m.startswith("hmpc.tools.cmd_")]
    return [
        f"{m} imports {d}"
        for m in cmds
        for d in sorted(graph[m])
        if d.startswith("hmpc.tools.cmd_") or d == "hmpc.tools.cli"
    ]


def test_subcommand_modules_never_import_each_other():
    bad = _cmd_cross_imports(_graph(_sources()))
    assert not bad, "share through tools/common.py:\n" + "\n".join(bad)


def test_subcommand_rule_catches_a_planted_violation():
    sources = _sources()
    texts = {"hmpc.tools.cmd_drive": "def run(a):\n    from hmpc.tools.cmd_simulate import x\n"}
    assert _cmd_cross_imports(_graph(sources, texts)) == [
        "hmpc.tools.cmd_drive imports hmpc.tools.cmd_simulate"
    ]


# ------------------------------------------------------------------------ metrics, plots
def _imports_of_module(sources, mod, texts=None) -> set[str]:
    return {name for _, name in imports_of(sources[mod], (texts or {}).get(mod))}


def test_the_drive_loop_takes_its_metrics_from_the_metrics_module():
    sources = _sources()
    graph = _graph(sources)
    drive = [m for m in sources if m.startswith("hmpc.controller.actuation.")]
    bad = [
        f"{m} -> {' -> '.join(c)}"
        for m in drive
        if m != "hmpc.controller.actuation.vehicle_node"
        and (c := _reaches(graph, m, "hmpc.controller.closed_loop"))
    ]
    assert not bad, "\n".join(bad)
    assert "hmpc.controller.metrics" in sources


def _plotters(sources, texts=None) -> list[str]:
    return [
        m
        for m in sources
        if not m.startswith("hmpc.models.report")
        and any(
            n == "matplotlib" or n.startswith("matplotlib.")
            for n in _imports_of_module(sources, m, texts)
        )
    ]


def test_plots_live_in_models_report():
    bad = _plotters(_sources())
    assert not bad, "plot through hmpc.models.report: " + ", ".join(bad)


def test_plot_rule_catches_a_planted_violation():
    sources = _sources()
    texts = {"hmpc.tools.cmd_simulate": "def f():\n    import matplotlib.pyplot as plt\n"}
    assert _plotters(sources, texts) == ["hmpc.tools.cmd_simulate"]


# ------------------------------------------------------------------------ circles
def test_no_import_circles():
    sources = _sources()
    cycles = _cycles(_package_faces(_graph(sources), sources))
    assert not cycles, "import circles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_circle_rule_catches_a_planted_violation():
    """The params <-> plant circle, hidden in a function, is found."""
    sources = _sources()
    texts = {"hmpc.models.params": "def f():\n    from hmpc.models.plant import HybridPlant\n"}
    cycles = _cycles(_package_faces(_graph(sources, texts), sources))
    assert ["hmpc.models.params", "hmpc.models.plant"] in cycles


# ------------------------------------------------------------------------ size, history
def _long(sources: dict[str, Path], counts: dict[str, int] | None = None) -> list[str]:
    counts = counts or {
        m: len(p.read_text(encoding="utf-8").splitlines()) for m, p in sources.items()
    }
    return [
        f"{sources[m].relative_to(REPO_DIR)}: {n} lines"
        for m, n in sorted(counts.items())
        if n > MAX_LINES
    ]


def test_no_module_over_800_lines():
    bad = _long(_sources())
    assert not bad, "split by responsibility:\n" + "\n".join(bad)


def test_size_rule_catches_a_planted_violation():
    sources = _sources()
    assert len(_long(sources, {m: 801 if m == "hmpc.models.plant" else 10 for m in sources})) == 1


def _issue_mentions(texts: dict[str, str]) -> list[str]:
    return [
        f"{name}:{i}: {line.strip()}"
        for name, text in texts.items()
        for i, line in enumerate(text.splitlines(), 1)
        if ISSUE_RE.search(line)
    ]


def test_no_issue_numbers_in_code():
    """Project history lives in git log: no issue numbers in models/, controller/, tools/."""
    texts = {
        str(p.relative_to(REPO_DIR)): p.read_text(encoding="utf-8") for p in _sources().values()
    }
    bad = _issue_mentions(texts)
    assert not bad, "\n".join(bad)


def test_issue_rule_catches_a_planted_violation():
    assert (
        len(
            _issue_mentions(
                {"x.py": "a = 1  # the figure of issue 12\n# Issues 3 and 4\nx = 'tissue 5'\n"}
            )
        )
        == 2
    )


def test_nothing_points_at_the_shared_contract():
    """The contract and the house style live in docs/; only tests and benchmarks that read
    ../shared/data's extra recordings may name ../shared."""
    bad = []
    roots = [REPO_DIR / d for d in (*FOLDERS, "params", "docs")] + [
        REPO_DIR / "README.md",
        REPO_DIR / "Makefile",
    ]
    for root in roots:
        files = (
            [root]
            if root.is_file()
            else sorted(
                p
                for p in root.rglob("*")
                if p.is_file() and p.suffix in (".py", ".md", ".yaml", ".j2", ".txt", "")
            )
        )
        for p in files:
            if "data" in p.relative_to(REPO_DIR).parts:
                continue
            for i, line in enumerate(
                p.read_text(encoding="utf-8", errors="replace").splitlines(), 1
            ):
                if re.search(r"shared/(CONVENTIONS|STYLE)|\b(CONVENTIONS|STYLE)\.md", line):
                    bad.append(f"{p.relative_to(REPO_DIR)}:{i}")
    assert not bad, "point at docs/conventions.md or docs/style.md:\n" + "\n".join(bad)
