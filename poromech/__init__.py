"""poromech: frictional contact on fracture networks in (poro)elastic rock, with fracture flow.

``import poromech`` is meant to be a script's first line (docs/api.md): it imports
``dolfinx_solver``, which loads MPI (``mpi4py.MPI``, from the ``mpich`` wheel) before any DOLFINx
or PETSc module is imported. In this environment DOLFINx and petsc4py are binary wheels that find
``libmpi.so.12`` only once MPI is loaded, so a plain ``import dolfinx`` first fails. MPI is
initialized here: set ``mpi4py.rc`` options, if any, before importing poromech.
"""

import dolfinx_solver  # noqa: F401  (MPI first, before dolfinx/petsc4py)

__version__ = "0.1.0"
