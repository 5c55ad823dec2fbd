"""The numpy local step of ARAP: the best rotation by Newton steps on SO(3)
against the SVD, and the quaternion conversions."""
import numpy as np

from lmap_drake.deformation.rotations import (
    MatrixToQuaternion, PolarRotationQuaternion, PolarRotationSvd, QuaternionToMatrix)


def test_polar_rotation_matches_svd_including_reflections():
    rng = np.random.default_rng(3)
    M = rng.normal(size=(400, 3, 3))
    q0 = np.zeros((4, 400))
    q0[0] = 1.0
    R, q = PolarRotationQuaternion(M.transpose(1, 2, 0), q0)
    R = R.transpose(2, 0, 1)
    assert (np.linalg.det(M) < 0).sum() > 100
    assert np.allclose(R, PolarRotationSvd(M), atol=1e-6)
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.allclose(QuaternionToMatrix(q).transpose(2, 0, 1), R, atol=1e-6)
    assert np.allclose(QuaternionToMatrix(MatrixToQuaternion(R.transpose(1, 2, 0))),
                       R.transpose(1, 2, 0), atol=1e-12)
