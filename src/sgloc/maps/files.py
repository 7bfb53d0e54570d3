"""The graph-file reader and writer `SemanticGraph.load` / `.save` call (`GRAPH_FILES`).

The file formats live above the maps, in `sgloc.io.graph_files`, which registers its
`read_graph` / `write_graph` here when imported; `import sgloc` registers stand-ins that import
it on first use, so the formats are there whichever sgloc module a program imports first.
"""

from __future__ import annotations

from sgloc.errors import SglocError

TYPE_CHECKING = False  # typing is not imported: `import sgloc` imports this module
if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    import numpy as np

    GraphReader = Callable[[str | Path], tuple[np.ndarray, np.ndarray]]
    GraphWriter = Callable[..., Path]


class GraphFiles:
    """The registered graph-file reader (path -> (positions, labels)) and writer
    (path, positions, labels, edge_radius=... -> path); None until registered."""

    def __init__(self) -> None:
        self.reader: GraphReader | None = None
        self.writer: GraphWriter | None = None

    def register(self, reader: GraphReader, writer: GraphWriter) -> None:
        """Make `reader` and `writer` the functions `SemanticGraph.load` / `.save` call."""
        self.reader, self.writer = reader, writer

    def read(self, path: str | Path) -> tuple[np.ndarray, np.ndarray]:
        """(positions, labels) read from `path` by the registered reader."""
        if self.reader is None:
            raise SglocError(self._missing("reader", "read", path))
        return self.reader(path)

    def write(
        self, path: str | Path, positions: np.ndarray, labels: np.ndarray, edge_radius: float
    ) -> Path:
        """Write a graph to `path` with the registered writer; the path written."""
        if self.writer is None:
            raise SglocError(self._missing("writer", "written", path))
        return self.writer(path, positions, labels, edge_radius=edge_radius)

    @staticmethod
    def _missing(role: str, done: str, path: str | Path) -> str:
        return (
            f"{path}: no graph-file {role} is registered, so the graph cannot be {done}; "
            "import sgloc.io.graph_files (it registers the formats' reader and writer)."
        )


#: The reader and writer of graph files (filled by `sgloc.io.graph_files`).
GRAPH_FILES = GraphFiles()
