"""nrmicp — fast new relaxation modulus-based (NRM) solvers for large sparse implicit
complementarity problems ICP(q, A, ζ) and linear complementarity problems LCP(q, A).

    >>> import nrmicp
    >>> res = nrmicp.solve(A, q)                       # LCP
    >>> res = nrmicp.solve(A, q, zeta=lambda z: ...)   # ICP
"""
from ._api import METHODS, Affine, Result, Solver, Status, backends, residual, solve
from ._hierarchy import Hierarchy, HierarchyWarning
from ._inputs import ConversionWarning

__version__ = "0.1.0"
__all__ = ["solve", "Solver", "Affine", "Result", "Status", "METHODS", "backends", "residual",
           "Hierarchy", "ConversionWarning", "HierarchyWarning", "__version__"]

try:  # the certificate module is pure numpy/scipy
    from .certificate import Certificate, convergence_bound  # noqa: F401
    __all__ += ["convergence_bound", "Certificate"]
except ImportError:  # pragma: no cover
    pass
