"""Constants the compiled kernels and their numpy references share (no numba import)."""

#: Metres: a point set whose second principal standard deviation is at least this is not
#: collinear however long it is (a 1,000 km stretch of street mapped 240 m wide fixes the roll
#: about its line; by the ratio alone it would count as a line).
COLLINEAR_WIDTH = 5.0
