"""tools/regression_set.py: a stability label may differ only where the largest multiplier is 1
(to 1e-9) in both runs (a refined fold point's label is rounding)."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

_spec = importlib.util.spec_from_file_location(
    "regression_set", Path(__file__).resolve().parents[1] / "tools" / "regression_set.py"
)
regression_set = importlib.util.module_from_spec(_spec)
# (the tool switches the derivation cache and progress off in its process environment when
# imported: kept out of this test process, where the cache tests run after it)
_environ = dict(os.environ)
try:
    _spec.loader.exec_module(regression_set)
finally:
    os.environ.clear()
    os.environ.update(_environ)


def _branch(rle, mult):
    return {"stable_rle": rle, "max_multiplier": mult}


def test_a_label_flip_at_a_unit_multiplier_is_not_a_difference():
    old = _branch([["S", 2], ["U", 2]], [0.9, 1.0, 1.2, 1.3])
    new = _branch([["S", 1], ["U", 3]], [0.9, 1.0, 1.2, 1.3])
    assert regression_set._labels_differ_at_unit_multipliers(old, new)


def test_a_label_flip_elsewhere_is():
    old = _branch([["S", 2], ["U", 2]], [0.9, 0.99, 1.2, 1.3])
    new = _branch([["S", 1], ["U", 3]], [0.9, 0.99, 1.2, 1.3])
    assert not regression_set._labels_differ_at_unit_multipliers(old, new)
    # (and without the multipliers recorded, every flip counts)
    assert not regression_set._labels_differ_at_unit_multipliers(
        {"stable_rle": old["stable_rle"]}, {"stable_rle": new["stable_rle"]}
    )
