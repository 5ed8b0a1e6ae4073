"""Mixed-dimensional hybrid finite volume (HFV) Darcy flow in fractured porous media (DESIGN §5).

Importing the package first imports ``dolfinx_solver``, which must precede ``dolfinx`` and
``petsc4py``.
"""

import dolfinx_solver  # noqa: F401
