"""Poromechanics: Biot matrix, contact mechanics and HFV flow coupled by a fixed point."""
