"""The options object of the exact frequency response (:class:`ExactResponseOptions`).

Oracles: the documented meaning of ``ds_max`` (the parameter spacing of the output points is
at most ``ds_max`` of the window), the same call made with keywords, and the error contract
shared with the other options objects (an unknown keyword is a ParameterError naming it).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from perturb.errors import ParameterError
from perturb.model.builtins import builtin_model
from perturb.simulate.exact_response import (
    ExactResponseOptions,
    continue_orbits,
    exact_branches,
)

WINDOW = (1.5, 2.0)


def _osc():
    return builtin_model("nsd", k=-2, mu=0.05, F=2)


def _trace(**kw):
    return continue_orbits(_osc(), 1.6, [5.0, 0.0], WINDOW, **kw)


def test_options_object_and_keywords_are_the_same_call():
    by_kw = _trace(ds_max=0.02, tol=1e-9)
    by_obj = _trace(options=ExactResponseOptions(ds_max=0.02, tol=1e-9))
    # a keyword replaces the field of the options object
    mixed = _trace(options=ExactResponseOptions(ds_max=0.3, tol=1e-9), ds_max=0.02)
    for br in (by_obj, mixed):
        assert [p.parameter for p in br.points] == [p.parameter for p in by_kw.points]
        assert all(np.array_equal(p.y0, q.y0) for p, q in zip(br.points, by_kw.points, strict=True))


def test_ds_max_bounds_the_parameter_spacing():
    width = WINDOW[1] - WINDOW[0]
    for ds in (0.05, 0.01):
        p = np.array([q.parameter for q in _trace(options=ExactResponseOptions(ds_max=ds)).points])
        assert np.max(np.abs(np.diff(p))) <= ds * width * (1 + 1e-9)
        assert p.min() == WINDOW[0] and p.max() == WINDOW[1]


def test_unknown_or_foreign_keywords_are_named():
    with pytest.raises(ParameterError, match="bogus"):
        exact_branches(_osc(), WINDOW, bogus=1)
    # a field continue_orbits does not use is not silently ignored
    with pytest.raises(ParameterError, match="sweep_points"):
        _trace(sweep_points=3)
    with pytest.raises(ParameterError, match="ExactResponseOptions"):
        exact_branches(_osc(), WINDOW, options={"ds_max": 0.01})


def test_options_are_frozen_and_checked_by_the_functions():
    o = ExactResponseOptions()
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.tol = 1.0  # type: ignore[misc]
    with pytest.raises(ParameterError, match="ds_max"):
        _trace(options=ExactResponseOptions(ds_max=-1.0))
    with pytest.raises(ParameterError, match="sweep_points"):
        exact_branches(_osc(), WINDOW, options=ExactResponseOptions(sweep_points=-1))


def test_options_object_reaches_exact_through_the_front_door():
    """``frequency_response(osc, "exact", options=...)`` is the same as the keywords, for a
    traced window and for given frequencies."""
    from perturb.solve import frequency_response

    osc = _osc()
    opts = ExactResponseOptions(ds_max=0.02, max_seconds=120)
    by_object = frequency_response(osc, "exact", WINDOW, options=opts, progress=False)
    by_keywords = frequency_response(osc, "exact", WINDOW, ds_max=0.02, progress=False)
    assert len(by_object.branches) == len(by_keywords.branches) > 0
    for a, b in zip(by_object.branches, by_keywords.branches, strict=True):
        np.testing.assert_array_equal(a.omega, b.omega)
        np.testing.assert_array_equal(a.amplitude, b.amplitude)
    at = frequency_response(osc, "exact", frequencies=[1.7], options=opts, progress=False)
    assert all(np.all(b.omega == 1.7) for b in at.branches) and at.branches
