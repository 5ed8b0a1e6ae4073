"""poromech: frictional contact on fracture networks in (poro)elastic rock, with fracture flow.

``import poromech`` is meant to be a script's first line (docs/api.md): it imports
``dolfinx_solver``, which loads MPI (``mpi4py.MPI``, from the ``mpich`` wheel) before any DOLFINx
or PETSc module is imported. In this environment DOLFINx and petsc4py are binary wheels that find
``libmpi.so.12`` only once MPI is loaded, so a plain ``import dolfinx`` first fails. MPI is
initialized here: set ``mpi4py.rc`` options, if any, before importing poromech.
"""

import os

#: Environment variables in which MPI launchers (MPICH/Intel MPI, Open MPI) give the number of
#: ranks before MPI is initialized.
_LAUNCHER_SIZE = ("PMI_SIZE", "OMPI_COMM_WORLD_SIZE")


def _one_blas_thread_per_rank() -> None:
    """Under ``mpirun -n N`` (N > 1), one BLAS thread per rank unless the user chose otherwise.

    With the default of one OpenBLAS thread per core, a rank's dense kernels (MUMPS fronts, the
    condensed face problem of ``mixed``) compete for the cores with the other ranks, which
    poll for messages while they wait: the coupled six-fracture scene, ``mixed`` on m = 1 with
    2 ranks, took 11.3 s with two threads per rank and 7.1 s with one.
    """
    ranks = max((int(os.environ.get(k, "1") or 1) for k in _LAUNCHER_SIZE), default=1)
    if ranks > 1:
        for key in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
            os.environ.setdefault(key, "1")


_one_blas_thread_per_rank()

import dolfinx_solver  # noqa: E402, F401  (MPI first, before dolfinx/petsc4py)

__version__ = "0.1.0"
