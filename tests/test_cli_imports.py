"""netsim.cli builds only the parser a command needs (start-up latency), and that
parser parses exactly as the whole one does."""

from __future__ import annotations

import ast
import subprocess
import sys

import pytest

from netsim.cli import build_parser


def _subparsers(parser):
    return next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")


def test_top_level_listing_is_the_same():
    full, light = build_parser(), build_parser("")
    assert light.format_help() == full.format_help()
    names = {a.dest: a.help for a in _subparsers(full)._choices_actions}
    assert {a.dest: a.help for a in _subparsers(light)._choices_actions} == names


@pytest.mark.parametrize("argv", [
    ["run", "lcsys2022-heterogeneous", "--steps", "5", "--gains", "rate", "--rho", "0.5",
     "--ties", "highest", "--no-cache", "--no-progress"],
    ["analyze", "lcsys2022-homogeneous", "--tau-max", "4", "--workers", "2", "--json"],
    ["bench", "delay-tolerance", "lcsys2022-fig1", "--no-cache"],
    ["design", "lcsys2022-homogeneous", "--method", "lmi"],
    ["scenarios", "--json"],
])
def test_a_commands_parser_parses_as_the_whole_one(argv):
    assert vars(build_parser(argv[0]).parse_args(argv)) == vars(build_parser().parse_args(argv))
    sub = _subparsers(build_parser(argv[0])).choices[argv[0]]
    assert sub.format_help() == _subparsers(build_parser()).choices[argv[0]].format_help()


def test_help_and_run_do_not_import_what_they_do_not_use():
    code = ("import sys\nfrom netsim.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in ('netsim.bench', 'netsim.aoi', 'scipy.sparse', "
            "'networkx', 'cvxpy', 'matplotlib', 'mcap', 'simpy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip().splitlines()[-1]
    assert out == "[]"


#: What a command imports only when it needs it (issue 34's start-up): the optional
#: extras (plots, traces, sweeps on Dask), the gain design's solver (a warm gain cache
#: needs none), graphs (networkx: the lcsys2022 scenarios' cycle needs none) and the
#: estimators of other papers (AoI, fusion).
HEAVY = ("cvxpy", "matplotlib", "mcap", "dask", "distributed", "pandas", "networkx",
         "scipy.spatial", "netsim.aoi", "netsim.fusion", "netsim.estimators.aoi",
         "netsim.estimators.fusion", "netsim.models.dkfe", "netsim.bench", "netsim.traces")

_MAIN = ("import sys\nfrom netsim.cli import main\n"
         "try:\n    main({argv!r})\nexcept SystemExit:\n    pass\n"
         "print(sorted(m for m in {heavy!r} if m in sys.modules))")


def _heavy_after(argv: list[str], heavy: tuple[str, ...] = HEAVY) -> list[str]:
    """The ``heavy`` modules loaded by ``netsim ARGV`` in a fresh interpreter (by
    sys.modules; no timings)."""
    out = subprocess.run([sys.executable, "-c", _MAIN.format(argv=argv, heavy=heavy)],
                         capture_output=True, text=True, check=True).stdout
    return ast.literal_eval(out.strip().splitlines()[-1])


@pytest.mark.parametrize("argv", [["--help"], ["run", "--help"]])
def test_help_imports_no_heavy_module(argv):
    assert _heavy_after(argv, (*HEAVY, "scipy.sparse", "scipy.linalg", "simpy")) == []


def test_a_warm_run_imports_only_what_its_scenario_needs():
    argv = ["run", "lcsys2022-heterogeneous", "--steps", "5", "--trials", "1",
            "--no-progress"]
    _heavy_after(argv)  # warms the gain cache (the design imports cvxpy)
    assert _heavy_after(argv) == []


def test_aoi_options_import_the_aoi_estimators_only_when_given():
    argv = ["run", "lcsys2022-heterogeneous", "--steps", "5", "--trials", "1",
            "--no-progress", "--estimators", "aoi", "--ties", "highest"]
    assert "netsim.estimators.aoi" in _heavy_after(argv)


def test_the_light_weights_and_link_table_are_the_graph_ones():
    """The cycle and random networks' weights built from the links (no networkx) are
    the networkx graph's, draw for draw; the dense link table is the CSR one."""
    import dataclasses

    import numpy as np
    import scipy.sparse as sp
    from netsim.models import network as nw
    from netsim.models.scenario import resolve_scenario

    for n in (2, 3, 7, 40):
        for seed in range(3):
            for prob in (0.0, 0.2, 1.0):
                graph = nw.random_strongly_connected(n, prob, seed)
                src, dst = nw.random_links(n, prob, seed)
                assert np.array_equal(nw.random_weights(graph, seed),
                                      nw.link_random_weights(n, src, dst, seed))
                assert np.array_equal(nw.uniform_weights(graph),
                                      nw.link_uniform_weights(n, src, dst))
        cycle = np.arange(n)
        assert np.array_equal(nw.random_weights(nw.directed_cycle(n), 5),
                              nw.link_random_weights(n, cycle, (cycle + 1) % n, 5))
    for name in ("lcsys2022-heterogeneous", "aoi-example", "dkfe-example2"):
        scenario = resolve_scenario(name)
        dense = scenario.link_table
        sparse = dataclasses.replace(scenario, weights=sp.csr_array(scenario.weights)).link_table
        for field in ("src", "dst", "weight"):
            a, b = getattr(dense, field), getattr(sparse, field)
            assert a.dtype == b.dtype and np.array_equal(a, b)


def test_strong_connectivity_without_networkx_agrees():
    import networkx as nx
    import numpy as np
    from netsim.models.network import _strongly_connected_dense

    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 5, 9):
        for _ in range(40):
            adjacency = rng.random((n, n)) < rng.uniform(0.05, 0.6)
            graph = nx.from_numpy_array(adjacency.T.astype(int), create_using=nx.DiGraph)
            assert _strongly_connected_dense(adjacency) == nx.is_strongly_connected(graph)
