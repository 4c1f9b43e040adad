"""The one scene registry: every named scene at every named size, for the tests, the bench
(``nrmicp bench``) and benchmarks/. A size name means the same everywhere:

=============  ================================================================================
``tiny``       n of tens to hundreds: what a test affords (milliseconds)
``small``      n of a few thousand: the family sweep's default (``nrmicp bench --family``)
``medium``     n of ten thousand or more
``large``      n of tens of thousands (2D grids 128², the American put at n_space = 6400)
``realistic``  the sizes of the README's figure (``nrmicp bench``): the 2D obstacle at
               n = 261,121, the 3D obstacle at n = 103,823, thermoforming 2D at n = 16,129, the
               American put at n_space = 3200
=============  ================================================================================

Each size gives a scene's grid parameter: m (n = m²) for Bai and the 2D scenes, m (n = m³) for
obstacle_3d, n for the 1D scenes, n_space (n = n_space − 1) for the American and the game put, the
number of blocks for p_matrix_cycling, the refinements r for elastic contact (P1: n = 2·2^r·(2^{r+1}
+ 1); P2 at r has P1's n at r + 1, so the two have the same n at every size).

The box scenes (an upper bound or free unknowns; ``Problem.upper`` or ζ with -inf) are the last
six: the two-sided membranes, elastic contact P1/P2, the game put and the heated two-sided membrane
(its upper bound moves with the solution: an implicit upper bound).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

#: Every scene the registry builds, in the order of the family sweep's panels.
NAMES = ("bai_sym_lcp", "bai_nonsym_lcp", "bai_sym_icp", "bai_nonsym_icp", "bai_sym_affine",
         "obstacle_1d", "obstacle_2d", "obstacle_3d", "convection_obstacle", "p_matrix_cycling",
         "thermoforming_1d", "thermoforming_2d", "impulse_control", "american_put", "contact_disk_p1",
         "two_sided_1d", "two_sided_2d", "elastic_contact_p1", "elastic_contact_p2", "game_put",
         "two_sided_heated_2d")

_PARAMS = ("bai", "obstacle_1d", "obstacle_2d", "obstacle_3d", "convection_obstacle", "p_matrix_cycling",
           "thermoforming_1d", "thermoforming_2d", "impulse_control", "american_put", "contact_disk_p1",
           "two_sided_1d", "two_sided_2d", "elastic_contact_p1", "elastic_contact_p2", "game_put",
           "two_sided_heated_2d")
SIZES = {
    "tiny":      dict(zip(_PARAMS, (8, 63, 8, 6, 8, 4, 63, 8, 33, 100, 64, 63, 7, 3, 2, 100, 7))),
    "small":     dict(zip(_PARAMS, (64, 255, 32, 12, 32, 64, 255, 32, 65, 1600, 1024, 255, 31, 5, 4, 1600, 31))),
    "medium":    dict(zip(_PARAMS, (128, 1023, 64, 20, 64, 256, 1023, 64, 129, 3200, 4096, 1023, 63, 6, 5, 3200, 63))),
    "large":     dict(zip(_PARAMS, (256, 4095, 128, 32, 128, 1024, 4095, 128, 255, 6400, 16384, 4095, 127, 7, 6,
                                    6400, 127))),
    "realistic": dict(zip(_PARAMS, (512, 65535, 511, 47, 511, 4096, 65535, 127, 1023, 3200, 131072, 65535, 511, 8, 7,
                                    3200, 511))),
}


def parameter(name: str, size: str) -> int:
    """The grid parameter of scene ``name`` at ``size`` (see the module docstring)."""
    if size not in SIZES:
        raise ValueError(f"size must be one of {', '.join(SIZES)}; got {size!r}")
    return SIZES[size]["bai" if name.startswith("bai_") else name]


def build(name: str, size: str = "small", *, exact=None):
    """The :class:`nrmicp.scenes.Problem` named ``name`` at ``size``. ``exact``: compute the
    exact discrete solution (None: the scene's default; False saves the reference solve)."""
    from . import (american_put, bai, contact_disk_p1, convection_diffusion_obstacle, elastic_contact, game_put,
                   impulse_control, obstacle_1d, obstacle_2d, obstacle_3d, p_matrix_cycling, thermoforming_1d,
                   thermoforming_2d, two_sided_membrane_1d, two_sided_membrane_2d, two_sided_membrane_heated_2d)

    if name not in NAMES:
        raise ValueError(f"unknown scene {name!r}; choose from {', '.join(NAMES)}")
    m = parameter(name, size)
    kw = {} if exact is None else {"exact": exact}
    if name.startswith("bai_"):
        _, sym, kind = name.split("_")
        return bai(m, symmetric=sym == "sym", kind=kind)
    if name == "p_matrix_cycling":
        return p_matrix_cycling(m)
    if name == "american_put":
        return american_put(n_space=m, **kw)
    if name == "game_put":
        return game_put(n_space=m, **kw)
    if name.startswith("elastic_contact_"):
        return elastic_contact(name[-2:].upper(), m, **kw)
    builders = {"obstacle_1d": obstacle_1d, "obstacle_2d": obstacle_2d, "obstacle_3d": obstacle_3d,
                "convection_obstacle": convection_diffusion_obstacle, "thermoforming_1d": thermoforming_1d,
                "thermoforming_2d": thermoforming_2d, "impulse_control": impulse_control,
                "contact_disk_p1": contact_disk_p1, "two_sided_1d": two_sided_membrane_1d,
                "two_sided_2d": two_sided_membrane_2d, "two_sided_heated_2d": two_sided_membrane_heated_2d}
    return builders[name](m, **kw)


def catalog(size: str = "small") -> list:
    """One instance of every scene at ``size`` (for smoke tests and sweeps)."""
    return [build(name, size) for name in NAMES]


def scaled_lcp(problem):
    """(A, q) of a grid obstacle scene as the pure LCP in y = z − ψ, multiplied through by h²
    (the 5- or 7-point stencil with entries 4 or 6 and −1): absolute Res targets keep their
    meaning at every h (with the 1/h² scaling, rounding in Az alone is ~1e-7 at n = 10⁶)."""
    h2 = problem.reference["h"] ** 2
    A = sp.csr_matrix(problem.A * h2)
    A.sort_indices()
    q = h2 * (np.asarray(problem.q, dtype=float) + problem.A @ np.asarray(problem.zeta, dtype=float))
    return A, q

