"""Candidate matches by descriptor similarity (paper Eq. 1): `candidates.match_descriptors` (the
entry point), the approximate per-class index of large targets (`index`) and the compiled top-k
kernels (`similarity_kernels`)."""
