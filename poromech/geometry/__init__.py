"""Fractured domains as plain data: the domain, its named boundary pieces, the fractures.

:mod:`~poromech.geometry.plane` describes 2D domains (a polygon cut by fracture polylines) and
checks them; :mod:`~poromech.geometry.dfn` reads fracture networks from CSV files. No meshing,
no MPI.
"""
