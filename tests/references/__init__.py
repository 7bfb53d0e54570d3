"""The plain numpy references the compiled kernels are checked against, one module per stage
(`maps`, `descriptors`, `matching`, `consistency`, `rejection`, `estimation`, `acceptance`). The
shipped stages call their kernels directly; these slower, simpler versions exist only to test
them (tests/test_kernels.py and others, benchmarks/kernel_cache.py).
`references.paths.on_references()` runs the library on them instead of the kernels.
"""
