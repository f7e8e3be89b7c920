"""Dotted params keys and DVC's ``${...}`` interpolation (:mod:`abcgs.dotted`), shared by the cluster plan, the
preflight checks, the stage runner and the benchmarks."""

from __future__ import annotations

import pytest

from abcgs.dotted import has_key, interpolate, lookup, set_dotted

PARAMS = {"stylize": {"fast": {"k": 5}, "backend": None}, "experiments": {"e1": {"scene": "fern"}}, "n": 3}


def test_lookup_walks_mappings_and_names_the_missing_key() -> None:
    assert lookup(PARAMS, "stylize.fast.k") == 5
    assert lookup(PARAMS, "experiments.e1") == {"scene": "fern"}
    with pytest.raises(KeyError, match="stylize.fast.kk"):
        lookup(PARAMS, "stylize.fast.kk")
    with pytest.raises(KeyError, match=r"n\.x"):  # below a value that is not a mapping
        lookup(PARAMS, "n.x")
    assert lookup(PARAMS, "stylize.slow", {}) == {} and lookup(PARAMS, "n.x", None) is None


def test_has_key_counts_a_null_value_as_present() -> None:
    assert has_key(PARAMS, "stylize.backend") and has_key(PARAMS, "n")
    assert not has_key(PARAMS, "stylize.threads") and not has_key(PARAMS, "n.x")


def test_set_dotted_creates_the_mappings_on_the_way() -> None:
    tree: dict = {"fit": {"iterations": 10}}
    set_dotted(tree, "fit.iterations", 20)
    set_dotted(tree, "stylize.fast.k", 7)
    assert tree == {"fit": {"iterations": 20}, "stylize": {"fast": {"k": 7}}}


def test_interpolate_fills_key_item_fields_and_params_as_dvc_does() -> None:
    item = PARAMS["experiments"]["e1"]
    text = "out/${key}/${ item.scene }/k${stylize.fast.k}"
    assert interpolate(text, "e1", item, PARAMS) == "out/e1/fern/k5"
    assert interpolate("${item}", "tiny", "data/tiny", PARAMS) == "data/tiny"
    with pytest.raises(KeyError, match="item.path"):
        interpolate("${item.path}/images", "e1", item, PARAMS)
