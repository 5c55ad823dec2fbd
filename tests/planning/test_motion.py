import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from scipy.spatial.transform import Rotation, Slerp

from lmap_drake.planning.motion import CartesianPath


def test_cartesian_path_is_the_straight_line_and_the_slerp():
    rng = np.random.default_rng(0)
    for _ in range(20):
        X0 = RigidTransform(RotationMatrix(RollPitchYaw(rng.uniform(-3, 3, 3))), rng.normal(size=3))
        X1 = RigidTransform(RotationMatrix(RollPitchYaw(rng.uniform(-3, 3, 3))), rng.normal(size=3))
        path = CartesianPath(X0, X1, 0.05)
        n = len(path)
        d = np.linalg.norm(X1.translation() - X0.translation())
        angle = X0.rotation().InvertAndCompose(X1.rotation()).ToAngleAxis().angle()
        assert n == max(1, int(np.ceil(max(d / 0.05, angle / np.deg2rad(10)))))
        slerp = Slerp([0, 1], Rotation.from_matrix([X0.rotation().matrix(),
                                                    X1.rotation().matrix()]))
        for k, X in enumerate(path, 1):
            f = k / n
            assert np.allclose(X.translation(), (1 - f) * X0.translation() + f * X1.translation())
            assert np.allclose(X.rotation().matrix(), slerp(f).as_matrix(), atol=1e-12)
        assert path[-1].IsExactlyEqualTo(X1)
