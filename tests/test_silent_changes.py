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
