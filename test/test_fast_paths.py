"""The fitter's hand-rolled fast paths give the digits of the slower, general code they replace
(the golden fits depend on it): checked against that code on random input."""
from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from affordance_registration.core.transforms import axis_angle_matrix

_axis = st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3).filter(
    lambda a: math.fsum(x * x for x in a) > 1e-12)
_angle = st.one_of(st.floats(-10.0, 10.0), st.floats(-2e-3, 2e-3))


def _scipy_axis_angle(axis, angle):
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle, dtype=float)
    unit = axis / np.linalg.norm(axis) if axis.ndim == 1 else \
        axis / np.sqrt([a @ a for a in axis])[:, None]
    return Rotation.from_rotvec(unit * angle[..., None]).as_matrix()


@settings(max_examples=300, deadline=None)
@given(axes=st.lists(_axis, min_size=1, max_size=12), angles=st.data())
def test_axis_angle_matrix_has_scipys_digits(axes, angles):
    angle = angles.draw(st.lists(_angle, min_size=len(axes), max_size=len(axes)))
    for a, q in ((axes, angle), (axes[0], angle[0]), (axes[0], angle)):
        got, want = axis_angle_matrix(a, q if np.ndim(q) == 0 else np.array(q)), \
            _scipy_axis_angle(a, q)
        assert got.shape == want.shape
        assert np.array_equal(got, want)
