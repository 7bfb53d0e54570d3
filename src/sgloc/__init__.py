"""sgloc: multi-robot global localization on semantic graphs.

from sgloc import SemanticGraph, localize
res = localize(query_graph, target_graph, descriptor="histogram", rejection="neighbor")
res.transform  # T_target_query (4x4) or None when not localized

from sgloc import register
reg = register(src, dst, rejection="neighbor", noise_bound=2.5)  # matched points (m,3) each
reg.transform  # T_dst_src (4x4) or None when reg.success is False
"""

from sgloc.maps.files import GRAPH_FILES as _GRAPH_FILES  # loads no numeric library

TYPE_CHECKING = False  # typing is not imported: `import sgloc` stays light

__version__ = "0.1.0"

#: The public names and the module each comes from: imported on first use (PEP 562), so that
#: `import sgloc` (and the `sgloc` program's start-up) loads no numeric library.
_EXPORTS = {
    "LocalizationResult": "sgloc.pipeline.localizer",
    "Localizer": "sgloc.pipeline.localizer",
    "LocalizerConfig": "sgloc.pipeline.config",
    "NotLocalizedError": "sgloc.pipeline.localizer",
    "PreparedMap": "sgloc.pipeline.prepared",
    "RegistrationResult": "sgloc.pipeline.registration",
    "SemanticGraph": "sgloc.maps.graph",
    "SglocError": "sgloc.errors",
    "localize": "sgloc.pipeline.localizer",
    "localize_fleet": "sgloc.online.fleet",  # the fleet layer: beside localize
    "prepare": "sgloc.pipeline.prepared",
    "register": "sgloc.pipeline.registration",
}

__all__ = [
    "LocalizationResult",
    "Localizer",
    "LocalizerConfig",
    "NotLocalizedError",
    "PreparedMap",
    "RegistrationResult",
    "SemanticGraph",
    "SglocError",
    "__version__",
    "localize",
    "prepare",
    "register",
]

if TYPE_CHECKING:
    from sgloc.errors import SglocError
    from sgloc.maps.graph import SemanticGraph
    from sgloc.online.fleet import localize_fleet  # noqa: F401
    from sgloc.pipeline.config import LocalizerConfig
    from sgloc.pipeline.localizer import LocalizationResult, Localizer, NotLocalizedError, localize
    from sgloc.pipeline.prepared import PreparedMap, prepare
    from sgloc.pipeline.registration import RegistrationResult, register


def _read_graph(path):
    """`sgloc.io.graph_files.read_graph`, imported on first use (it then registers itself)."""
    from sgloc.io.graph_files import read_graph

    return read_graph(path)


def _write_graph(path, positions, labels, edge_radius=None):
    """`sgloc.io.graph_files.write_graph`, imported on first use (it then registers itself)."""
    from sgloc.io.graph_files import write_graph

    return write_graph(path, positions, labels, edge_radius=edge_radius)


#: `SemanticGraph.load` / `.save` read and write through the file formats of `sgloc.io`: this
#: package runs before any of its modules, so the formats are registered whichever is imported
#: first, and `import sgloc` still loads no numeric library.
_GRAPH_FILES.register(_read_graph, _write_graph)


def __getattr__(name: str):
    """A public name, imported from its module on first use."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'sgloc' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
