"""Meshes of fractured domains, distributed, with the cracked topology of the displacement space.

* :mod:`~poromech.mesh.generate`: gmsh meshes conforming to the fracture network (rank 0);
* :mod:`~poromech.mesh.imported`: meshes read from files;
* :mod:`~poromech.mesh.fractured`: the distributed connected mesh, its fracture faces with their
  orientation, the cracked topology and the displacement space with duplicated nodes;
* :mod:`~poromech.mesh.entities`: cell, facet and fracture-face geometry of the owned entities.
"""
