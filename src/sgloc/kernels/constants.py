"""Constants the compiled kernels and their numpy references share (no numba import)."""

#: Metres: a point set whose second principal standard deviation is at least this is not
#: collinear however long it is (a 1,000 km stretch of street mapped 240 m wide fixes the roll
#: about its line; by the ratio alone it would count as a line).
COLLINEAR_WIDTH = 5.0
#: Tukey's biweight cut-off in robust scales (95 % efficiency under Gaussian noise).
TUKEY_C = 4.685
#: The median absolute residual times this is a Gaussian's standard deviation (MAD scale).
MAD_SCALE = 1.4826
