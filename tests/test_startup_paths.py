"""Start-up (issue 34): what the warm command paths import, and the fast paths being exact.

Properties, not timings: a warm ``netsim run`` / ``netsim analyze`` of the lcsys2022
scenarios imports no module it does not use (checked by ``sys.modules`` in a fresh
interpreter; a run: not scipy.sparse, SimPy or importlib.metadata either), and the
structured spectral radius' direct CSR kernel gives the same bits as the ``S @ x`` it
replaces.
"""

from __future__ import annotations

import ast
import subprocess
import sys

import numpy as np
import pytest
import scipy.sparse as sp
from netsim.models import augmented as aug

_MAIN = ("import sys\nfrom netsim.cli import main\n"
         "try:\n    main({argv!r})\nexcept SystemExit:\n    pass\n"
         "print(sorted(m for m in {names!r} if m in sys.modules))")

#: Never needed by a warm run of the lcsys2022 scenarios (their gains come from the
#: cache, their graph is a cycle, they write no trace and draw no plot); the bar is
#: off (--no-progress), and the joint-system analysis of a plant with simple
#: eigenvalues needs no Schur form.
#: Issue 34: the vectorised step of a run this small forms its consensus products with
#: numpy alone (no scipy.sparse, and so no numpy.f2py or numpy.testing that scipy's
#: helpers pull in), builds its results without the event kernel (SimPy), and the gain
#: cache's fingerprint reads library versions without importlib.metadata.
NOT_FOR_RUN = ("cvxpy", "matplotlib", "mcap", "networkx", "dask", "pandas",
               "scipy.linalg", "scipy.spatial", "tqdm", "netsim.calibrate",
               "netsim.bench", "netsim.reproduce", "netsim.claims", "netsim.aoi",
               "netsim.fusion", "netsim.traces", "scipy.sparse", "numpy.f2py",
               "numpy.testing", "simpy", "netsim.kernel", "netsim.links",
               "importlib.metadata", "numpy.ma")

#: analyze never needs the event kernel, the engines or a bar; a warm one reads its exact
#: radii from the radius cache (netsim.radiuscache), so it needs no ARPACK
#: (scipy.sparse.linalg, which imports scipy.linalg) either.
NOT_FOR_ANALYZE = ("cvxpy", "matplotlib", "mcap", "networkx", "dask", "pandas", "simpy",
                   "tqdm", "netsim.kernel", "netsim.vectorised", "netsim.calibrate",
                   "netsim.bench", "netsim.aoi", "netsim.fusion", "netsim.traces",
                   "scipy.sparse", "scipy.linalg")


def test_the_kernel_names_the_light_modules_objects():
    """``netsim.kernel`` re-exports the result type and constants it used to define."""
    from netsim import kernel, trialresult

    for name in trialresult.__all__:
        assert getattr(kernel, name) is getattr(trialresult, name)


def _loaded(argv: list[str], names: tuple[str, ...]) -> list[str]:
    out = subprocess.run([sys.executable, "-c", _MAIN.format(argv=argv, names=names)],
                         capture_output=True, text=True, check=True).stdout
    return ast.literal_eval(out.strip().splitlines()[-1])


def test_a_warm_run_loads_no_unused_module():
    argv = ["run", "lcsys2022-heterogeneous", "--steps", "5", "--trials", "2",
            "--no-progress"]
    _loaded(argv, NOT_FOR_RUN)  # warms the gain cache (the design may import cvxpy)
    assert _loaded(argv, NOT_FOR_RUN) == []


def test_a_warm_analyze_loads_no_unused_module():
    argv = ["analyze", "lcsys2022-homogeneous", "--tau-max", "12", "--no-progress"]
    _loaded(argv, NOT_FOR_ANALYZE)
    assert _loaded(argv, NOT_FOR_ANALYZE) == []


def test_an_analysis_without_arpack_does_not_import_it(monkeypatch):
    """Radii computed now, all by dense eigenvalues (N n (tau + 1) rows up to
    AUGMENTED_DENSE_SIZE_THRESHOLD): scipy.sparse is not imported; one more tau, by
    ARPACK, imports it."""
    monkeypatch.setenv("NETSIM_RADIUS_CACHE", "off")
    last_dense = aug.AUGMENTED_DENSE_SIZE_THRESHOLD // 24 - 1  # N n = 24
    argv = ["analyze", "lcsys2022-homogeneous", "--tau-max", str(last_dense),
            "--no-progress"]
    _loaded(argv, ())  # warms the gain cache
    assert _loaded(argv, ("scipy.sparse",)) == []
    argv[3] = str(last_dense + 1)
    assert _loaded(argv, ("scipy.sparse",)) == ["scipy.sparse"]


def _reference_power(row: aug._FirstRow, X: np.ndarray, q: int) -> np.ndarray:
    """``M^q X`` by the shift-and-multiply recursion with scipy's ``S @ x``."""
    Nn, R = row.Nn, row.R
    buf = np.empty(((q + R) * Nn, *X.shape[1:]))
    buf[q * Nn:] = X
    for t in range(q - 1, -1, -1):
        buf[t * Nn:(t + 1) * Nn] = row._S @ buf[(t + 1) * Nn:(t + 1 + R) * Nn]
    return buf[: R * Nn]


@pytest.mark.parametrize("width", [0, 1, 5])
def test_the_direct_csr_kernel_gives_the_bits_of_the_sparse_product(width):
    rng = np.random.default_rng(7)
    N, n, depth = 9, 3, 4
    P = np.where(rng.random((N, N)) < 0.4, rng.random((N, N)), 0.0)
    np.fill_diagonal(P, 0.5)
    P /= P.sum(axis=1, keepdims=True)
    delays = np.where(P != 0, rng.integers(0, depth, (N, N)), 0)
    np.fill_diagonal(delays, 0)
    A = rng.standard_normal((n, n)) / 2
    G = np.stack([np.eye(n) - 0.3 * np.outer(rng.standard_normal(n), np.eye(n)[0])
                  for _ in range(N)])
    row = aug._FirstRow(G, P, delays, aug._delay_blocks(A, depth, True), kind="bsr")
    D = row.Nn * row.R
    X = rng.standard_normal((D, width) if width else D)
    for q in (1, 3, 8):
        got = row.companion_power(X, q)
        assert np.array_equal(got, _reference_power(row, X, q))  # bit for bit
    # the same matrix as a dense product, to round-off (independent of scipy's kernel)
    S = row._S.toarray()
    assert np.allclose(row.apply(X[: D]), S @ X, rtol=1e-13, atol=1e-13)
    assert sp.issparse(row._S)


def test_a_plant_with_simple_eigenvalues_gets_its_eigenvector_as_the_mode_subspace():
    from netsim.models.jointsystem import _invariant_subspace

    rng = np.random.default_rng(3)
    A = rng.standard_normal((5, 5))
    values = np.linalg.eigvals(A)
    for lam in values:
        V = _invariant_subspace(A, complex(lam), 1e-5, 1)
        assert V.shape == (5, 1)
        assert np.isclose(np.linalg.norm(V), 1.0)
        assert np.linalg.norm(A @ V - lam * V) < 1e-10 * np.linalg.norm(A)
        # the same subspace as the ordered Schur form's (the path for clusters)
        W = _invariant_subspace(A, complex(lam), 1e-5, 0)
        assert W.shape == (5, 1)
        assert abs(abs(np.vdot(V[:, 0], W[:, 0])) - 1.0) < 1e-10
