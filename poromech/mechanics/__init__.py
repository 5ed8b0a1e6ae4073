"""Contact mechanics: the model (spaces, unknowns, forms), its semi-smooth Newton and the physics.

* :mod:`~poromech.mechanics.model`: unknowns and compiled forms of the contact problem;
* :mod:`~poromech.mechanics.newton`: the semi-smooth Newton (PETSc SNES, own line search);
* :mod:`~poromech.mechanics.condensed`: ``mixed`` solved condensed onto the fracture faces;
* :mod:`~poromech.mechanics.coercivity`: the coercivity bound of symmetric Nitsche;
* :mod:`~poromech.mechanics.physics`: the mechanics physics behind the time loop.
"""
