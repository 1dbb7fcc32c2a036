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
