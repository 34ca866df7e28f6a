"""The piecewise-affine system data (perturb.model.affine): validation and region bookkeeping."""

import numpy as np
import pytest

from perturb.errors import ModelError
from perturb.model.affine import PiecewiseAffineSystem


def _clearance(k_contact: float = 4.0, gap: float = 1.0, jump: float = 0.0):
    """x'' + 0.1 x' + x + k (|x| - gap)_+ sign x = cos t, states (x, x'); a step force of
    size ``jump`` at contact makes the field discontinuous."""
    A_free = [[0.0, 1.0], [-1.0, -0.1]]
    A_contact = [[0.0, 1.0], [-1.0 - k_contact, -0.1]]
    return PiecewiseAffineSystem.build(
        ("x", "x'"),
        [((1.0, 0.0), gap, "x = gap"), ((1.0, 0.0), -gap, "x = -gap")],
        {
            (1, 1): (A_contact, (0.0, k_contact * gap - jump)),
            (-1, 1): (A_free, (0.0, 0.0)),
            (-1, -1): (A_contact, (0.0, -k_contact * gap + jump)),
        },
        inputs=[(1.0, (0.0, 1.0), (0.0, 0.0))],
        period=2 * np.pi,
    )


def test_regions_fields_and_continuity():
    sys_ = _clearance()
    assert sys_.n == 2 and sys_.continuous == (True, True)
    assert sys_.pattern(np.array([2.0, 0.0])) == (1, 1)
    assert sys_.pattern(np.array([0.0, 3.0])) == (-1, 1)
    assert sys_.pattern(np.array([-2.0, 0.0])) == (-1, -1)
    # x = 2 in contact: x'' = -x - 4 (x - 1) - 0.1 x' + cos t
    y = np.array([2.0, 0.5])
    np.testing.assert_allclose(sys_.field(0.0, y), [0.5, -2.0 - 4.0 - 0.05 + 1.0])
    assert _clearance(jump=0.3).continuous == (False, False)
    with pytest.raises(ModelError, match=r"names no region"):
        sys_.region((1, -1))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"state_names": ()}, "empty"),
        ({"state_names": ("x", "x")}, "distinct"),
        ({"surfaces": [((0.0, 0.0), 1.0)]}, "normal is zero"),
        ({"surfaces": [((1.0,), 1.0)]}, r"shape \(1,\)"),
        ({"regions": {(1, 1, 1): ([[0, 1], [-1, 0]], (0, 0))}}, "pattern of 2 signs"),
        ({"regions": {(1, 1): ([[0, 1]], (0, 0))}}, "A has shape"),
        ({"inputs": [(-1.0, (0, 1), (0, 0))]}, "positive frequency"),
        ({"period": 0.0}, "positive number"),
    ],
)
def test_bad_input_names_the_value(kwargs, match):
    base = {
        "state_names": ("x", "x'"),
        "surfaces": [((1.0, 0.0), 1.0), ((1.0, 0.0), -1.0)],
        "regions": {(1, 1): ([[0, 1], [-1, 0]], (0, 0))},
    }
    base.update(kwargs)
    with pytest.raises(ModelError, match=match):
        PiecewiseAffineSystem.build(**base)
