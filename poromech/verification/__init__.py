"""Known answers for tests and benchmarks: jump errors, manufactured and 1D flow solutions."""
