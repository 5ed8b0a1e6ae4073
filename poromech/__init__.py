"""poromech: frictional contact on fracture networks in (poro)elastic rock, with fracture flow."""

__version__ = "0.1.0"
