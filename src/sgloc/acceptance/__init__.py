"""The acceptance stage: is an estimated alignment backed by evidence, or could chance explain it?

One entry point, `accept(...) -> Verdict` (`stage.py`), used by the localizer. Modules by job:

- `config.py`: `AcceptanceConfig` (the test) holding `EvidenceConfig` (which candidates count)
  and `VerificationConfig` (the whole-map verification of small queries);
- `evidence.py`: `select_evidence`, the one choice of the candidates that count, and
  `spatially_distinctive` (the ratio test against rivals at other places);
- `chance.py`: `ChanceModel` (same-class target objects near moved query objects), the NFA
  (`log10_nfa`, `nfa_over_radii`) and the one `confidence` formula;
- `rivals.py`: `distinct_from` (a different alignment) and `runner_up` (the best distinct one);
- `repetition.py`: `check_repetition` -> `Repetition`, the checks for a repeating layout (the
  target's self-similar shifts as rivals; the agreement of the claimed overlap);
- `assessment.py`: `assess` -> `Assessment`, the a-contrario test (its docstring: the model);
- `verification.py`: `verify_small_query` -> `Verification`, a small query's whole geometry
  checked against the map;
- `stage.py`: `accept` -> `Verdict`: evidence, test, then the verification fallback.
"""

from sgloc.acceptance.assessment import (
    DOF4_SPREAD_FACTOR,
    Assessment,
    assess,
    inlier_spread,
    required_spread,
)
from sgloc.acceptance.chance import (
    MIN_RADIUS_FRACTION,
    RADIUS_FRACTIONS,
    ChanceModel,
    confidence,
    log10_colocation_p,
    log10_nfa,
    nfa_over_radii,
    pair_consistency,
    per_object_min,
    permutation_lambda,
    triangle_count,
)
from sgloc.acceptance.config import AcceptanceConfig, EvidenceConfig, VerificationConfig
from sgloc.acceptance.evidence import select_evidence, spatially_distinctive
from sgloc.acceptance.repetition import (
    Repetition,
    check_repetition,
    log10_rival_weight,
    self_similar_shifts,
)
from sgloc.acceptance.rivals import distinct_from, runner_up
from sgloc.acceptance.stage import Verdict, accept, verifies
from sgloc.acceptance.verification import (
    ClassTree,
    SearchContext,
    Verification,
    self_rival,
    verify_small_query,
)

__all__ = [
    "DOF4_SPREAD_FACTOR",
    "MIN_RADIUS_FRACTION",
    "RADIUS_FRACTIONS",
    "AcceptanceConfig",
    "Assessment",
    "ChanceModel",
    "ClassTree",
    "EvidenceConfig",
    "Repetition",
    "SearchContext",
    "Verdict",
    "Verification",
    "VerificationConfig",
    "accept",
    "assess",
    "check_repetition",
    "confidence",
    "distinct_from",
    "inlier_spread",
    "log10_colocation_p",
    "log10_nfa",
    "log10_rival_weight",
    "nfa_over_radii",
    "pair_consistency",
    "per_object_min",
    "permutation_lambda",
    "required_spread",
    "runner_up",
    "select_evidence",
    "self_rival",
    "self_similar_shifts",
    "spatially_distinctive",
    "triangle_count",
    "verifies",
    "verify_small_query",
]
