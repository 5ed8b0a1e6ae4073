"""Known answers for tests and benchmarks.

Jump errors, manufactured and 1D flow solutions, consolidation errors and fluid volumes of
coupled runs.
"""
