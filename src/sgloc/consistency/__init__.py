"""Pairwise consistency of candidate matches, the graph behind rejection and acceptance: all
pairs (`pairwise.consistency_bits`, the entry point), pairs within a radius (`local`), and a
random sample of pairs for very many candidates (`sampled`). Compiled kernels:
`pairwise_kernels`, `triangle_kernels`, `local_kernels`."""
