"""What netsim changes in a request is said, never silent (issue 29)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from netsim.models.scenario import ScenarioWarning, parse_scenario


def _data(topology: str, agents: int = 5) -> dict:
    return {"name": "x", "plant": {"A": [[0.5]], "C": [[[1.0]]] * agents, "Q": 0.1, "R": 0.1},
            "network": {"topology": topology, "agents": agents, "weights": "lazy-metropolis",
                        "seed": 3}}


@pytest.mark.parametrize("topology", ["cycle", "random"])
def test_lazy_metropolis_says_that_it_makes_the_links_symmetric(topology):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sc = parse_scenario(_data(topology))
    P = np.asarray(sc.weights.toarray() if hasattr(sc.weights, "toarray") else sc.weights)
    used = int(np.count_nonzero(P) - P.shape[0])
    assert np.allclose(P, P.T)  # symmetric: every link both ways
    words = [str(w.message) for w in caught if issubclass(w.category, ScenarioWarning)]
    assert any("network.weights" in m and f"({used} links)" in m for m in words), words


def test_no_word_when_nothing_changes():
    data = _data("edges", 3)
    data["network"]["edges"] = [[0, 1], [1, 0], [1, 2], [2, 1]]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        parse_scenario(data)
    assert not [w for w in caught if "lazy-metropolis" in str(w.message)]


def test_numpy_noise_is_not_printed_beside_the_result():
    """A run whose state overflows float64 (rho(A) = 1.04 over 20,000 steps) makes numpy
    warn; the command prints its result and verdict, not numpy's RuntimeWarnings (in a
    subprocess: pytest would capture the warnings itself)."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "netsim.cli", "run",
                           "lcsys2022-heterogeneous", "--steps", "20000", "--trials", "3",
                           "--engine", "events",
                           "--no-progress"], capture_output=True, text=True, timeout=300,
                          stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stderr
    assert "compensated" in proc.stdout
    assert "RuntimeWarning" not in proc.stderr and "overflow" not in proc.stderr


def test_a_resumed_sweep_writes_the_same_csv_as_an_uninterrupted_one(tmp_path, capsys):
    """Kill simulated by cutting the results file after its first row: the resumed sweep
    computes the rest and its CSV is byte for byte the uninterrupted sweep's."""
    from netsim.cli import main

    args = ["bench", "sweep", "lcsys2022-heterogeneous", "--taus", "0,2", "--trials", "2",
            "--steps", "20", "--workers", "1", "--no-progress"]
    whole = tmp_path / "whole"
    whole.mkdir()
    assert main([*args, "--out", str(whole / "r.jsonl"), "--csv", str(whole / "r.csv")]) == 0
    part = tmp_path / "part"
    part.mkdir()
    rows = (whole / "r.jsonl").read_text().splitlines(keepends=True)
    assert len(rows) == 2
    (part / "r.jsonl").write_text(rows[0])  # the first cell finished, the second did not
    assert main([*args, "--out", str(part / "r.jsonl"), "--csv", str(part / "r.csv")]) == 0
    capsys.readouterr()
    assert (part / "r.csv").read_bytes() == (whole / "r.csv").read_bytes()
