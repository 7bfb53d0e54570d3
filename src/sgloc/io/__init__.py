"""Readers and writers: graph files (pcd, json, npz) and pose files."""

from sgloc.io.graph_files import read_graph, write_graph

__all__ = ["read_graph", "write_graph"]
