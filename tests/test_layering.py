"""Import layering (DESIGN.md): ``models`` never loads ``traces``; ``bench`` never loads ``cli``.

Each check runs in a fresh interpreter, so modules other tests imported do not count.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(code: str) -> tuple[list[str], str]:
    """Run ``code`` in a fresh interpreter: the netsim modules it loaded, and its output."""
    script = (f"{code}\nimport json, sys\n"
              "print(json.dumps(sorted(m for m in sys.modules if m.startswith('netsim'))))")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         check=True, cwd=ROOT)
    *lines, last = out.stdout.strip().splitlines()
    return json.loads(last), "\n".join(lines)


def _loaded_after(code: str) -> list[str]:
    return _run(code)[0]


def test_models_scenario_and_linkmodels_load_no_traces_module():
    loaded = _loaded_after("import netsim.models.linkmodels, netsim.models.scenario")
    assert "netsim.models.scenario" in loaded
    assert [m for m in loaded if m.startswith("netsim.traces")] == []


def test_trace_delay_source_is_registered_and_loads_traces_only_when_called(tmp_path):
    """Without importing netsim.traces first, a trace-driven delay still finds its reader
    (registered by the netsim package) and the reader's error names the file."""
    missing = tmp_path / "nope.mcap"
    code = (
        "import netsim.models.scenario, sys\n"
        "from netsim.models.linkmodels import load_trace_replay\n"
        "assert not any(m.startswith('netsim.traces') for m in sys.modules)\n"
        "try:\n"
        f"    load_trace_replay({str(missing)!r})\n"
        "except ValueError as exc:\n"
        "    print('ERR', exc)\n"
    )
    loaded, output = _run(code)
    assert "netsim.traces.linkdelays" in loaded
    assert output.startswith("ERR ") and str(missing) in output


def test_no_models_module_imports_traces():
    for path in sorted((ROOT / "models").glob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            bad = [n for n in names if n.startswith("netsim.traces")]
            assert not bad, f"{path.name} imports {bad}"


@pytest.mark.parametrize("module", ["netsim.bench", "netsim.bench.command"])
def test_bench_does_not_load_the_cli(module):
    assert "netsim.cli" not in _loaded_after(f"import {module}")


# -- no import cycles ----------------------------------------------------------------
#
# Every import of netsim's own modules, at module level or inside a function (a lazy
# import is still a dependency: it only moves the cycle to run time), except those under
# ``if TYPE_CHECKING:``. ``from package import name`` depends on ``package.name`` when that
# is a module, else on the package's __init__; importing a submodule is not counted as
# depending on its parent package (an __init__ re-exporting its submodules is no cycle).

#: Source folders and the package each installs as (pyproject.toml's package-dir).
PACKAGE_DIRS = {"netsim": "netsim", "models": "netsim.models",
                "estimators": "netsim.estimators", "traces": "netsim.traces"}

#: Cycles allowed for now, each the set of modules of one strongly connected component
#: (none: the budget <-> runner <-> vectorised <-> vectrace cycle was removed in issue 30).
KNOWN_CYCLES: list[set[str]] = []


def _modules() -> dict[str, Path]:
    found = {}
    for folder, package in PACKAGE_DIRS.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = list(path.relative_to(ROOT / folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join([package, *parts])] = path
    return found


def _runtime_imports(tree: ast.AST):
    """Import statements of ``tree``, skipping ``if TYPE_CHECKING:`` blocks."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            stack.extend(node.orelse)
            continue
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node
        stack.extend(ast.iter_child_nodes(node))


def import_graph():
    import networkx as nx

    modules = _modules()
    graph = nx.DiGraph()
    graph.add_nodes_from(modules)
    for name, path in modules.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in _runtime_imports(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                base = node.module or ""
                if node.level:
                    up = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                    base = ".".join([*up, *([node.module] if node.module else [])])
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                           for a in node.names]
            for target in targets:
                # ``import netsim.traces.reader`` names a module; a dotted name that is not
                # one (``import netsim.models.x as y`` of a removed module) counts its package
                while target and target not in modules:
                    target = target.rpartition(".")[0]
                if target and target != name:
                    graph.add_edge(name, target)
    return graph


def _cycles(graph) -> list[set[str]]:
    import networkx as nx

    return [set(c) for c in nx.strongly_connected_components(graph) if len(c) > 1]


def test_import_graph_sees_the_imports():
    graph = import_graph()
    assert graph.has_edge("netsim.bench.delay_tolerance", "netsim.bench.claims")
    assert graph.has_edge("netsim.claims.checks", "netsim.bench.claims")  # lazy
    assert graph.has_edge("netsim.claims.searches", "netsim.bench.delay_tolerance")  # lazy
    assert graph.has_edge("netsim.traces.stepread", "netsim.traces.schemas")
    assert len(graph) > 80


def test_no_import_cycles_but_the_known_one():
    unexpected = [sorted(c) for c in _cycles(import_graph())
                  if not any(c <= known for known in KNOWN_CYCLES)]
    assert unexpected == [], f"import cycles: {unexpected}"


def test_no_import_cycles_at_all():
    assert _cycles(import_graph()) == []


def test_bench_never_imports_the_claims():
    """The claims sit above the bench: they run it (claims.checks) and read its claim
    rows (netsim.bench.claims); the bench imports nothing of netsim.claims."""
    graph = import_graph()
    bad = [(a, b) for a, b in graph.edges
           if a.startswith("netsim.bench") and b.startswith("netsim.claims")]
    assert bad == []
