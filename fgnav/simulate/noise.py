"""Measurement noise shared by the simulators (a seeded ``numpy.random.Generator`` in, SI units)."""

from __future__ import annotations

import numpy as np

from factors.geometry import tangent_basis


def perturb_directions(u: np.ndarray, sigma_rad: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Rotate unit vectors (M,3) by isotropic tangent-plane noise of 1σ ``sigma_rad`` per axis."""
    B = tangent_basis(u)
    n = rng.standard_normal((len(u), 2)) * np.asarray(sigma_rad, dtype=float).reshape(-1, 1)
    theta = np.linalg.norm(n, axis=1)
    d = np.einsum("mi,mij->mj", n, B) / np.where(theta > 0, theta, 1.0)[:, None]
    out = np.cos(theta)[:, None] * u + np.sin(theta)[:, None] * d
    return out / np.linalg.norm(out, axis=1, keepdims=True)
