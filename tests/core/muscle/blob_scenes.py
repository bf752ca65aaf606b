"""Random scenes shared by the blobby mesher's tests."""

import numpy as np


def rotations(rng, n):
    """``n`` uniformly random proper rotations (3, 3) whose columns are the principal axes."""
    q, rr = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    q = q * np.sign(np.diagonal(rr, axis1=1, axis2=2))[:, None, :]
    q[np.linalg.det(q) < 0, :, 0] *= -1
    return q
