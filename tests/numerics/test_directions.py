"""imucal.numerics.directions: distinct directions counted against angles known by construction."""

import numpy as np
import pytest

from imucal.numerics.directions import distinct_orientations


def _tilted(axis: np.ndarray, deg: float) -> np.ndarray:
    """A unit vector ``deg`` degrees away from the unit ``axis``."""
    other = np.cross(axis, [0.3, 0.5, 0.8])
    other /= np.linalg.norm(other)
    a = np.radians(deg)
    return np.cos(a) * axis + np.sin(a) * other


def test_six_faces_are_six_and_repeats_do_not_count():
    faces = np.vstack([np.eye(3), -np.eye(3)])
    assert distinct_orientations(faces) == 6
    assert distinct_orientations(np.repeat(faces, 4, axis=0)) == 6


def test_length_does_not_matter():
    faces = np.vstack([np.eye(3), -np.eye(3)]) * np.arange(1, 7)[:, None] * 1e3
    assert distinct_orientations(faces) == 6


@pytest.mark.parametrize("deg, want", [(5.0, 1), (14.5, 1), (15.5, 2), (90.0, 2)])
def test_the_threshold_is_the_angle_between_directions(deg, want):
    z = np.array([0.0, 0.0, 1.0])
    assert distinct_orientations(np.array([z, _tilted(z, deg)])) == want


def test_the_threshold_is_a_setting():
    z = np.array([0.0, 0.0, 1.0])
    v = np.array([z, _tilted(z, 30.0)])
    assert distinct_orientations(v, min_angle_deg=25.0) == 2
    assert distinct_orientations(v, min_angle_deg=35.0) == 1


def test_a_fan_of_directions_counts_every_step_of_the_fan():
    # 0, 20, ..., 340 degrees round a circle: each 20 degrees from its neighbours.
    a = np.radians(np.arange(0, 360, 20))
    v = np.column_stack([np.cos(a), np.sin(a), np.zeros_like(a)])
    assert distinct_orientations(v) == 18
    assert distinct_orientations(v, min_angle_deg=30.0) == 9  # every other one


def test_empty_is_zero():
    assert distinct_orientations(np.zeros((0, 3))) == 0
