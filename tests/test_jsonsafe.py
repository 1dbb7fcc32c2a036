"""netsim.models.jsonsafe: the one JSON-number convention of every ``--json`` output."""

from __future__ import annotations

import json
import math
from functools import partial
from pathlib import Path
from types import MappingProxyType

import numpy as np
import pytest
from netsim.models.jsonsafe import json_default, json_number, json_tree


def test_json_number_nan_inf_none():
    assert json_number(None) is None
    assert json_number(math.nan) is None
    assert json_number(np.float32("inf")) == "inf"
    assert json_number(-math.inf) == "-inf"
    assert json_number(np.int64(3)) == 3.0


def test_json_tree_numpy_scalars_and_nested_containers():
    tree = {"a": (np.float64(0.5), np.int32(2), np.bool_(True)), "b": [math.nan, -math.inf],
            "c": "text", "d": None}
    out = json_tree(tree)
    assert out == {"a": [0.5, 2, True], "b": [None, "-inf"], "c": "text", "d": None}
    assert type(out["a"][1]) is int and type(out["a"][2]) is bool
    json.dumps(out, allow_nan=False)


def test_json_tree_arrays_become_json_safe_lists():
    """An array inside the tree (netsim.fusion, netsim.sweep results) is a nested list."""
    out = json_tree({"m": np.array([[1.0, np.nan], [np.inf, 2.0]]), "i": np.arange(2)})
    assert out == {"m": [[1.0, None], ["inf", 2.0]], "i": [0, 1]}
    assert json.dumps(out, allow_nan=False) == '{"m": [[1.0, null], ["inf", 2.0]], "i": [0, 1]}'


def test_json_tree_any_mapping_and_string_keys():
    """Any mapping is a dict; ``str_keys`` makes a sort_keys dump sort integer keys as the
    strings it writes (netsim.sweep's canonical rows)."""
    proxy = MappingProxyType({10: 1.0, 2: math.nan})
    assert json_tree(proxy) == {10: 1.0, 2: None}
    out = json_tree(proxy, str_keys=True)
    assert out == {"10": 1.0, "2": None}
    assert json.dumps(out, sort_keys=True) == '{"10": 1.0, "2": null}'
    assert json_tree({"x": [{3: np.float64(1.5)}]}, str_keys=True) == {"x": [{"3": 1.5}]}


def test_json_default_numpy_values():
    dumps = partial(json.dumps, default=json_default)
    assert dumps({"a": np.arange(3), "b": np.float32(0.5), "c": np.int64(7),
                  "d": np.bool_(False)}) == '{"a": [0, 1, 2], "b": 0.5, "c": 7, "d": false}'


def test_json_default_strict_raises_and_fallback_encodes():
    with pytest.raises(TypeError, match="not JSON-able"):
        json.dumps({"p": Path("x")}, default=json_default)
    assert json.dumps({"p": Path("x"), "a": np.zeros(1)}, sort_keys=True,
                      default=partial(json_default, fallback=str)) == '{"a": [0.0], "p": "x"}'
