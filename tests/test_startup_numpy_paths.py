"""The light paths of a warm run (issue 34) against the paths they stand in for.

* the vectorised step's consensus products with numpy alone (small runs, no
  scipy.sparse) against scipy's CSR kernel: the same canonical CSR form, the same
  row sums and the same product bits, and whole engine runs equal bit for bit
  whichever path is taken (uniform and random delays, each consensus rule);
* the gain cache's light version reader against importlib.metadata (the fingerprint
  keeps its meaning), including which of two installs of a distribution it finds;
* the compiled-step choice (``NETSIM_NUMBA``) taken from the task, not the worker's
  environment (:mod:`netsim.taskoptions`), also through a Dask LocalCluster.
"""

from __future__ import annotations

from importlib import metadata

import numpy as np
import pytest
import scipy.sparse as sp
from netsim.models.seeding import child_sequence

from netsim import gaincache, taskoptions, vectorised
from tests.helpers import lcsys, with_delays


def _random_entries(rng: np.random.Generator, rows: int, cols: int, density: float):
    mask = rng.random((rows, cols)) < density
    mask[rng.integers(rows)] = False  # a row without entries
    r, c = np.nonzero(mask)
    order = rng.permutation(len(r))  # given in no particular order
    data = rng.standard_normal(len(r))
    data[: min(2, len(data))] = -0.0  # signed zeros must come out as scipy's do
    return data[order], r[order], c[order]


@pytest.mark.parametrize("seed", range(4))
def test_numpy_csr_matches_scipy_form_sums_and_product_bits(seed):
    rng = np.random.default_rng(seed)
    rows, cols, width = 7, 15, 12
    data, r, c = _random_entries(rng, rows, cols, 0.3)
    indptr, indices, values = vectorised._csr_parts(data, r, c, rows)
    ref = sp.csr_matrix((data, (r, c)), shape=(rows, cols))  # canonical after COO -> CSR
    assert np.array_equal(indptr, ref.indptr)
    assert np.array_equal(indices, ref.indices)
    assert np.array_equal(values, ref.data)
    assert np.array_equal(vectorised._csr_row_sums(indptr, values),
                          np.asarray(ref.sum(axis=1)).ravel())
    x = rng.standard_normal((cols, width))
    x[0, :3] = [np.inf, -np.inf, np.nan]  # non-finite inputs propagate alike
    x[1, :3] = [1e300, -1e300, 1e300]
    mine = np.empty((rows, width))
    theirs = np.empty((rows, width))
    with np.errstate(all="ignore"):
        got = vectorised._csr_product_into((indptr, indices, values), mine)(x)
        want = vectorised._sparse_product_into(ref, theirs)(x)
    assert got is mine
    # bit for bit, NaNs included (compare the bytes)
    assert got.tobytes() == want.tobytes()
    # and the product itself, to round-off, against a dense one (finite part)
    finite = np.isfinite(want).all(axis=1)
    with np.errstate(all="ignore"):
        dense = ref.toarray() @ np.where(np.isfinite(x), x, 0.0)
    assert np.allclose(got[finite], dense[finite])


def _runs(scenario, family, gains, monkeypatch, force_numpy: bool):
    monkeypatch.setattr(vectorised, "NUMPY_PRODUCT_MAX_WORK",
                        10**18 if force_numpy else -1)
    assert vectorised._use_scipy(scenario, 3, 40) is not force_numpy
    seeds = [child_sequence(5, "trial", t) for t in range(3)]
    return vectorised.run_batch(scenario, family, gains, seeds, 40,
                                record_delays=True, kernel="numpy").results


@pytest.mark.parametrize(("family", "delays"), [
    ("compensated", {"model": "homogeneous", "tau": 3}),
    ("uncompensated", {"model": "homogeneous", "tau": 2}),
    ("compensated", {"model": "asynchronous", "tau": 4}),
    ("uncompensated", {"model": "heterogeneous", "tau": 3, "seed": 2022}),
    ("block", {"model": "asynchronous", "tau": 3}),
])
def test_the_engine_gives_the_same_bits_with_numpy_or_scipy_products(family, delays,
                                                                     monkeypatch):
    from netsim.estimators.gains import GainDesign

    scenario = with_delays(lcsys(), **delays)
    # any gains will do for comparing two ways of computing one recursion (no LMI)
    L = tuple(0.3 * np.asarray(C, dtype=float).T for C in scenario.plant.C)
    gains = GainDesign(L=L, K=tuple(Li @ np.asarray(C) for Li, C in
                                    zip(L, scenario.plant.C, strict=True)),
                       rho=0.5, certified_rate=None, certified=False, method="given",
                       solver="none", status="given", message="")
    light = _runs(scenario, family, gains, monkeypatch, force_numpy=True)
    heavy = _runs(scenario, family, gains, monkeypatch, force_numpy=False)
    for a, b in zip(light, heavy, strict=True):
        assert a.estimates.tobytes() == b.estimates.tobytes()
        assert a.squared_errors.tobytes() == b.squared_errors.tobytes()
        assert np.array_equal(a.effective_delays, b.effective_delays)
        assert a.diverged_at == b.diverged_at
        assert (a.messages_sent, a.messages_delivered, a.messages_discarded) == \
            (b.messages_sent, b.messages_delivered, b.messages_discarded)


def test_sparse_weights_always_take_scipy():
    scenario = lcsys()
    assert not vectorised._use_scipy(scenario, 20, 300)  # the warm run's own size
    sparse = lcsys(weights=sp.csr_array(np.asarray(scenario.weights)))
    assert vectorised._use_scipy(sparse, 1, 1)


@pytest.mark.parametrize("name", ["netsim", "numpy", "scipy", "cvxpy", "clarabel",
                                  "no-such-distribution-here"])
def test_the_light_version_reader_agrees_with_importlib_metadata(name):
    try:
        want = metadata.version(name)
    except metadata.PackageNotFoundError:
        want = None
    assert gaincache._installed_version(name) == want


def test_the_light_version_reader_takes_the_first_install_on_the_path(tmp_path,
                                                                      monkeypatch):
    first, second = tmp_path / "a", tmp_path / "b"
    for folder, version in ((first, "1.2.3"), (second, "9.9.9")):
        info = folder / f"Fake_Dist.x-{version}.dist-info"
        info.mkdir(parents=True)
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: fake-dist.x\n"
                                       f"Version: {version}\n\nbody Version: 0\n")
    monkeypatch.syspath_prepend(str(second))
    monkeypatch.syspath_prepend(str(first))
    assert gaincache._installed_version("fake-dist-x") == "1.2.3"
    assert metadata.version("fake-dist-x") == "1.2.3"  # the same rule, independently


def test_the_numba_choice_travels_with_the_task(monkeypatch):
    if not vectorised.numba_available():
        pytest.skip("numba not installed")
    monkeypatch.setenv("NETSIM_NUMBA", "1")
    options = taskoptions.snapshot()
    assert options["NETSIM_NUMBA"] == "1"
    monkeypatch.delenv("NETSIM_NUMBA")
    assert vectorised.choose_kernel() == "numpy"  # this process' environment
    with taskoptions.applied(options):
        assert vectorised.choose_kernel() == "numba"  # the client's choice
    # unset on the client: the task says so, whatever the worker's environment
    options = taskoptions.snapshot()
    assert options["NETSIM_NUMBA"] == ""
    monkeypatch.setenv("NETSIM_NUMBA", "1")
    with taskoptions.applied(options):
        assert vectorised.choose_kernel() == "numpy"


def _kernel_cell(params, seed, context):
    from netsim.vectorised import choose_kernel

    return {"kernel": choose_kernel()}


def test_a_local_cluster_worker_runs_the_clients_choice(monkeypatch):
    """Workers started before the client sets NETSIM_NUMBA (their environment lacks it)."""
    if not vectorised.numba_available():
        pytest.skip("numba not installed")
    distributed = pytest.importorskip("distributed")
    import cloudpickle

    import tests.test_startup_numpy_paths as here
    from netsim.sweep import grid, run_sweep

    cloudpickle.register_pickle_by_value(here)  # the workers need not import tests/
    monkeypatch.delenv("NETSIM_NUMBA", raising=False)
    try:
        with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                      dashboard_address=None) as cluster, \
                distributed.Client(cluster) as client:
            on_worker = client.run(lambda: __import__("os").environ.get("NETSIM_NUMBA"))
            assert set(on_worker.values()) == {None}
            monkeypatch.setenv("NETSIM_NUMBA", "1")  # the client's choice, after the start
            rows = run_sweep(_kernel_cell, grid(n=[1, 2]), dask_address=client,
                             progress=False).rows
    finally:
        cloudpickle.unregister_pickle_by_value(here)
    assert [r["result"]["kernel"] for r in rows] == ["numba", "numba"]


def test_the_fingerprint_is_the_same_whichever_way_versions_are_read(monkeypatch):
    import sys

    from netsim.estimators.gains import design_request

    scenario = lcsys()
    request = design_request(scenario)
    with_metadata = gaincache.fingerprint(scenario, request)  # importlib.metadata loaded
    monkeypatch.delitem(sys.modules, "importlib.metadata")  # as in a warm run
    monkeypatch.setattr(metadata, "version", None)  # it must not be called
    assert gaincache.fingerprint(scenario, request) == with_metadata


@pytest.mark.parametrize(("delays", "tau_max"), [
    ({"model": "homogeneous", "tau": 2}, 3),   # one of the analysed rows: reused
    ({"model": "homogeneous", "tau": 4}, 2),   # beyond tau_max: computed on its own
    ({"model": "heterogeneous", "tau": 3, "seed": 2022}, 3),  # not homogeneous
])
def test_the_scenarios_own_delays_get_the_radii_of_their_own_matrix(delays, tau_max):
    """analyze reuses a homogeneous row for the scenario's own delays only when they are
    that row's pattern; the realised radii are those of the scenario's delay matrix."""
    from netsim.estimators.gains import GainDesign

    from netsim.analysis import _exact_pair, analyze
    from netsim.runner import fixed_delay_matrix

    scenario = with_delays(lcsys(), **delays)
    L = tuple(0.3 * np.asarray(C, dtype=float).T for C in scenario.plant.C)
    gains = GainDesign(L=L, K=tuple(Li @ np.asarray(C) for Li, C in
                                    zip(L, scenario.plant.C, strict=True)),
                       rho=0.5, certified_rate=None, certified=False, method="given",
                       solver="none", status="given", message="")
    calls = []
    report = analyze(scenario, gains, tau_max, workers=1, progress=calls.append)
    fixed = fixed_delay_matrix(scenario)
    plant = scenario.plant
    want = _exact_pair((scenario.weights, plant.A, plant.C, L, fixed, int(fixed.max())))
    got = report.realised
    assert (got["rho_compensated"], got["rho_uncompensated"], got["bound_eq26"]) == want
    assert len(calls) == tau_max + 2  # every tau and the scenario's own delays
