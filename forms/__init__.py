"""UFL forms of poromech (installed as ``poromech.forms``): pure UFL, no PETSc or MPI."""
