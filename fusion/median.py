"""The geometric median of floor points: where a victim lies, from its fixes.

The point minimising the sum of Euclidean distances to the fixes. Unlike their mean
(or a Kalman filter's weighted mean), it does not follow a few stray fixes: up to
half of them can lie anywhere and it stays among the rest.

Computed on the smoothed distance sqrt(d^2 + eps^2) by Newton's method with a
backtracking line search. Weiszfeld's iteration, the usual one, divides by the
distance to each fix and crawls (its error shrinks by a constant factor near 1 per
step) where the median lies on or near a fix, which a victim's fixes often do.
Smoothed, the cost is strictly convex and twice differentiable, so Newton's method
converges fast from anywhere, and the minimum is the median's to within n eps in
total distance; at eps = 1 mm, far inside a fix's scatter of tens of centimetres.
"""

from __future__ import annotations

import numpy as np

from fusion.camera import FloatArray


def geometric_median(
    points: FloatArray, eps_m: float = 0.001, tol_m: float = 1e-7, max_iterations: int = 100
) -> FloatArray:
    """The geometric median of ``points`` (N, 2), N >= 1, smoothed by ``eps_m``."""
    z = np.asarray(points, dtype=float)
    if z.ndim != 2 or z.shape[0] == 0 or z.shape[1] != 2:
        raise ValueError(f"geometric_median needs an (N, 2) array with N >= 1, got {z.shape}")
    eps2 = eps_m * eps_m

    def cost(y: FloatArray) -> float:
        return float(np.sqrt(((z - y) ** 2).sum(axis=1) + eps2).sum())

    y: FloatArray = np.median(z, axis=0)  # coordinate-wise: a robust start
    f = cost(y)
    for _ in range(max_iterations):
        d = z - y
        s = np.sqrt((d**2).sum(axis=1) + eps2)
        grad = -(d / s[:, None]).sum(axis=0)
        hess = np.eye(2) * (1.0 / s).sum() - np.einsum("i,ij,ik->jk", s**-3, d, d)
        step = -np.linalg.solve(hess, grad)  # positive definite: eps > 0
        t = 1.0
        while True:  # Armijo backtracking: each step lowers the cost
            y_next = y + t * step
            f_next = cost(y_next)
            if f_next <= f + 1e-4 * t * float(grad @ step):
                break
            t *= 0.5
            if t < 1e-12:
                return y
        if float(np.linalg.norm(y_next - y)) < tol_m:
            return y_next
        y, f = y_next, f_next
    return y
