"""Files: XDMF series, fracture tables, summary, checkpoints, probes, reading results, pictures.

Writers (:mod:`~poromech.io.xdmf`, :mod:`~poromech.io.output`, :mod:`~poromech.io.checkpoint`,
:mod:`~poromech.io.probes`) are collective and crash-safe; readers (:mod:`~poromech.io.results`,
:mod:`~poromech.io.plot`) are serial and need no DOLFINx.
"""
