"""Semantic maps: the graph of objects (`graph.SemanticGraph`, the entry point), sightings
associated into objects (`association`), the canonical vertex order at the localizer's entry
(`canonical`), the structures stages build from a graph once (`prepared_graph.PreparedGraph`),
same-class neighbour search (`spatial`), class tables (`classes`), the scene's lengths
(`scale`, `units`) and the graph-file reader and writer `sgloc.io` registers (`files`).
Compiled kernels: `canonical_kernels`, `neighbor_kernels`."""
