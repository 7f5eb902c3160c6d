"""The Proto-symbol Space (thesis ch. 2): left-to-right HMMs (``hmm``, ``likelihood``), their eq.
2.4 distances (``distance``), metric MDS (``mds``), the space (``space``: build, recognise, generate,
emphasise), association (``association``), the space's file (``spacefile``), growth by clips
(``growth``), recognition's open set (``recognition``, ``novelty``, ``conformal``), motion features
(``features``). Imports ``motion``, ``io``, ``bodies`` (torques as sensor channels) and the base
modules; never the bus.

The public API is :data:`__all__`, importable from here (``from shared.pss import ProtoSymbolSpace``);
each name is loaded from its module when first used, so importing the package costs nothing.

References
----------
T. Inamura, "Proto-symbol space", doctoral thesis, 2012 (``../shared/seed/``), the method and
its equation numbers. T. Inamura, I. Toshima, H. Tanie, Y. Nakamura, "Embodied symbol emergence
based on mimesis theory", International Journal of Robotics Research 23(4), 2004. L. R. Rabiner,
"A tutorial on hidden Markov models and selected applications in speech recognition", Proc.
IEEE 77(2), 1989 (Baum-Welch, forward-backward). A. Bhattacharyya, Bull. Calcutta Math. Soc. 35,
1943 (eq. 2.4). J. de Leeuw, 1977, and I. Borg, P. Groenen, Modern Multidimensional Scaling,
2005 (SMACOF). V. Vovk, A. Gammerman, G. Shafer, Algorithmic Learning in a Random World, 2005
(conformal calibration of the open set).
"""

from __future__ import annotations

import importlib

#: public name -> the module that defines it
_WHERE = {
    "ProtoSymbolSpace": "space", "ProtoSymbol": "symbol", "SpaceParams": "symbol", "Recognition": "symbol",
    "Association": "symbol", "LeftToRightHMM": "hmm", "fit_hmm": "hmm", "hmm_distance": "distance",
    "distance_matrix": "distance", "smacof": "mds", "place_point": "mds", "Embedding": "mds", "combine": "synthesis",
    "point_weights": "synthesis", "generate": "synthesis", "MotionFeatures": "features", "decide": "recognition",
    "Decision": "recognition", "Calibration": "recognition",
}
__all__ = sorted(_WHERE)


def __getattr__(name: str):
    if name not in _WHERE:
        raise AttributeError(f"module 'shared.pss' has no attribute {name!r}")
    return getattr(importlib.import_module(f"shared.pss.{_WHERE[name]}"), name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
