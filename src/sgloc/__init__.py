"""sgloc: multi-robot global localization on semantic graphs.

from sgloc import SemanticGraph, localize
res = localize(query_graph, target_graph, descriptor="histogram", rejection="neighbor")
res.transform  # T_target_query (4x4) or None when not localized

from sgloc import register
reg = register(src, dst, rejection="neighbor", noise_bound=2.5)  # matched points (m,3) each
reg.transform  # T_dst_src (4x4) or None when reg.success is False
"""

from sgloc.errors import SglocError
from sgloc.maps.graph import SemanticGraph
from sgloc.pipeline.config import LocalizerConfig
from sgloc.pipeline.localizer import LocalizationResult, Localizer, NotLocalizedError, localize
from sgloc.pipeline.prepared import PreparedMap, prepare
from sgloc.pipeline.registration import RegistrationResult, register

__version__ = "0.1.0"


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


def __getattr__(name: str):
    """`sgloc.localize_fleet`, re-exported beside localize: the fleet layer (online session,
    pose graph) is imported on first use, not by `import sgloc`."""
    if name == "localize_fleet":
        from sgloc.online.fleet import localize_fleet

        return localize_fleet
    raise AttributeError(f"module 'sgloc' has no attribute {name!r}")
