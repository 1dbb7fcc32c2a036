"""The scalable certificate of the local gain design (issue 34).

:func:`netsim.models.augmented.delay_free_rho_bound` bounds rho(A-hat) from above by a
weighted infinity norm (linear work); :func:`netsim.estimators.gains.design_local` uses
it above ``LOCAL_SEARCH_MAX_STATES`` and falls back to the exact (ARPACK) radius when it
does not certify; the gain cache stores and re-verifies the certificate.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp
from netsim.estimators import gains as gains_mod
from netsim.estimators.gains import (
    BOUND_STATUS,
    certificate_text,
    design_for_scenario,
    design_local,
    design_request,
)
from netsim.models.augmented import (
    delay_free_closed_loop,
    delay_free_rho_bound,
    delay_free_spectral_radius,
    spectral_radius,
    weighted_norm_bound,
)
from netsim.models.scenario import load_scenario

from netsim import gaincache

#: The plant of examples/geometric-100k.toml (sensor i mod 4 measures one state).
A100K = np.array([
    [0.90, 0.30, 0.00, 0.00, 0.00, 0.00],
    [-0.30, 0.90, 0.00, 0.00, 0.00, 0.00],
    [0.00, 0.20, 0.95, 0.20, 0.00, 0.00],
    [0.00, 0.00, -0.20, 0.95, 0.00, 0.00],
    [0.00, 0.00, 0.00, 0.00, 1.01, 0.00],
    [0.00, 0.00, 0.00, 0.00, 0.00, 1.04],
])
SENSORS = (0, 2, 4, 5)


def _instance(seed: int) -> tuple[np.ndarray, np.ndarray, list, list]:
    """A random small instance of the block structure p_ij (I - L_i C_i) A."""
    r = np.random.default_rng(seed)
    N, n = int(r.integers(2, 9)), int(r.integers(1, 5))
    P = r.random((N, N)) * (r.random((N, N)) < 0.5)
    np.fill_diagonal(P, r.random(N) + 0.1)
    if seed % 2:
        P = P / P.sum(axis=1, keepdims=True)
    if seed % 5 == 0:
        P = P * np.where(r.random((N, N)) < 0.3, -1.0, 1.0)  # signed weights
    A = r.standard_normal((n, n)) * r.uniform(0.2, 1.3) / math.sqrt(n)
    if seed % 7 == 0 and n > 1:  # defective A: a Jordan block (eigenvector basis unusable)
        A = 0.8 * np.eye(n) + np.diag(np.ones(n - 1), 1)
    C = [r.standard_normal((int(r.integers(1, n + 1)), n)) for _ in range(N)]
    L = [r.standard_normal((n, Ci.shape[0])) * 0.4 for Ci in C]
    return P, A, C, L


@pytest.mark.parametrize("chunk", range(4))
def test_bound_is_an_upper_bound_on_the_exact_radius(chunk: int) -> None:
    certified = 0
    for seed in range(chunk * 100, chunk * 100 + 100):
        P, A, C, L = _instance(seed)
        exact = spectral_radius(delay_free_closed_loop(P, A, C, L))
        Ps = sp.csr_array(P) if seed % 3 else P
        b = delay_free_rho_bound(Ps, A, C, L, max_iter=40)
        assert b.bound >= exact * (1 - 1e-12), (seed, b.bound, exact)
        assert np.all(b.weights > 0)
        # the stored weights reproduce the bound in one step (what the cache verifies)
        again = weighted_norm_bound(Ps, A, C, L, b.weights, b.basis)
        assert again == pytest.approx(b.bound, rel=1e-12)
        certified += b.bound < 1.0
    assert certified > 0  # the property is not vacuous


def test_any_positive_weights_give_an_upper_bound() -> None:
    r = np.random.default_rng(7)
    for seed in range(30):
        P, A, C, L = _instance(1000 + seed)
        exact = spectral_radius(delay_free_closed_loop(P, A, C, L))
        W = r.uniform(0.01, 10.0, size=(P.shape[0], A.shape[0]))
        for basis in ("identity", "eigenvectors"):
            assert weighted_norm_bound(P, A, C, L, W, basis) >= exact * (1 - 1e-12)


def _geometric_toml(n_agents: int, seed: int = 0) -> str:
    C = ", ".join("[[" + ", ".join("1.0" if c == s else "0.0" for c in range(6)) + "]]"
                  for s in SENSORS)
    rows = ",\n    ".join("[" + ", ".join(f"{v:.2f}" for v in row) + "]" for row in A100K)
    radius = math.sqrt(10.0 / (math.pi * n_agents))
    return f"""name = "geometric-{n_agents}"
[run]
steps = 5
trials = 1
seed = 0
estimators = ["compensated"]

[plant]
A = [
    {rows},
]
C = [{C}]
sensors = {n_agents}
Q = 0.004
R = 0.004

[network]
topology = "geometric"
agents = {n_agents}
radius = {radius!r}
weights = "random"
seed = {seed}

[delays]
model = "homogeneous"
tau = 3

[gains]
method = "auto"
"""


@pytest.fixture(scope="module")
def geometric(tmp_path_factory):
    """The geometric-100k structure at N = 2100 (N n = 12,600: the bound's range)."""
    path = tmp_path_factory.mktemp("geo") / "geometric.toml"
    path.write_text(_geometric_toml(2100))
    return load_scenario(path)


def test_bound_certifies_the_geometric_structure_at_small_n() -> None:
    import pathlib
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        path = pathlib.Path(folder) / "g.toml"
        path.write_text(_geometric_toml(200, seed=3))
        sc = load_scenario(path)
    P = sp.csr_array(sc.weights)
    C = [np.atleast_2d(np.asarray(c, dtype=float)) for c in sc.plant.C]
    L = [0.6 * c.T @ np.linalg.pinv(c @ c.T) for c in C]
    b = delay_free_rho_bound(P, A100K, C, L)
    exact = spectral_radius(delay_free_closed_loop(P.toarray(), A100K, C, L))
    assert b.basis == "eigenvectors"
    assert exact <= b.bound < 1.0


def test_design_local_uses_the_bound_above_the_search_range(geometric) -> None:
    design = design_for_scenario(geometric)
    assert design.method == "local-scaled-projection"
    assert design.status == f"{BOUND_STATUS}-eigenvectors"
    assert design.certified and design.rho < 1.0
    assert len(design.certificate_weights) == 1
    exact = delay_free_spectral_radius(geometric.weights, geometric.plant.A,
                                       geometric.plant.C, design.L, method="structured")
    assert exact <= design.rho
    assert "rigorous upper bound" in design.message
    text = certificate_text(design.certified, design.status, design.rho)
    assert text.startswith(f"certified by {BOUND_STATUS}-eigenvectors: rho(A-hat) <= ")


def test_design_local_tau1_bounds_rho_design(geometric) -> None:
    A = 0.9 * A100K  # the plant of the example has rho_design(A^2) > 1 at gamma = 0.6
    design = design_local(geometric.weights, A, geometric.plant.C, tau1=1)
    assert design.status.startswith(BOUND_STATUS)
    assert len(design.certificate_weights) == 2
    exact = delay_free_spectral_radius(geometric.weights, A @ A,
                                       geometric.plant.C, design.L, method="structured")
    assert exact <= design.rho_design < 1.0


def test_failed_bound_falls_back_to_arpack(monkeypatch) -> None:
    """Signed weights: rho(|M|) > 1 > rho(A-hat), so the bound cannot certify."""
    monkeypatch.setattr(gains_mod, "LOCAL_SEARCH_MAX_STATES", 0)
    r = np.random.default_rng(0)
    blocks = []
    for _ in range(60):
        Q, _ = np.linalg.qr(r.standard_normal((3, 3)))
        blocks.append(0.9 * Q)
    P = sp.csr_array(sp.block_diag(blocks))
    N = P.shape[0]
    A = np.array([[1.0]])
    C = [np.array([[1.0]])] * N
    b = delay_free_rho_bound(P, A, C, [np.array([[0.1]])] * N)
    assert b.bound >= 1.0
    design = design_local(P, A, C, gamma=0.1)
    exact = spectral_radius(delay_free_closed_loop(P.toarray(), A, C, design.L))
    assert design.status == "structured-arpack"
    assert design.rho == pytest.approx(exact, rel=1e-8)
    assert design.certified and exact < 1.0
    assert "does not certify" in design.message
    assert design.certificate_weights == ()
    assert certificate_text(True, design.status, design.rho).endswith("(ARPACK)")


def test_cache_round_trip_keeps_the_certificate(geometric, tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("NETSIM_CACHE_DIR", str(tmp_path))
    request = design_request(geometric)
    fresh = design_for_scenario(geometric)
    gaincache.cached_design(geometric, request, lambda: fresh)
    key = gaincache.fingerprint(geometric, request)
    path = tmp_path / f"{key}.npz"
    back = gaincache.read_entry(path, key, geometric, request)
    assert back.status == fresh.status
    assert back.rho == fresh.rho
    assert back.message == fresh.message
    assert len(back.certificate_weights) == 1
    np.testing.assert_array_equal(back.certificate_weights[0], fresh.certificate_weights[0])
    # the certificate is verified on load: a stored bound that the weights do not give,
    # or weights that give another bound, are rejected
    tampered = fresh.__class__(**{**fresh.__dict__, "rho": fresh.rho * 0.9,
                                  "rho_design": fresh.rho * 0.9})
    with pytest.raises(gaincache.EntryError, match="bound"):
        gaincache.verify_design(tampered, geometric)
    W = fresh.certificate_weights[0].copy()
    W[0, 0] *= 1e-3
    moved = fresh.__class__(**{**fresh.__dict__, "certificate_weights": (W,)})
    with pytest.raises(gaincache.EntryError, match="bound"):
        gaincache.verify_design(moved, geometric)
    renamed = fresh.__class__(**{**fresh.__dict__, "status": f"{BOUND_STATUS}-schur"})
    with pytest.raises(gaincache.EntryError, match="basis"):
        gaincache.verify_design(renamed, geometric)
