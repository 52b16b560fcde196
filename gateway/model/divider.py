"""The read-out of the paper's Fig. 4b (eq. 18), re-exported.

The divider itself, ``Divider`` (sensor r from the supply V+ to the output node, R_ref to
ground, ``V_o = R_ref / (R_ref + r) * V+``, ``r = R_ref (V+ / V_o - 1)``), lives with the other
read-out front ends in ``frontend``; it and ``DividerStatus`` are re-exported here so
``gateway.model.divider.Divider`` keeps working. The paper's conductance line C = m F + n is
``static_curves.LineCurve``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .frontend import Divider, DividerStatus

__all__ = ["Divider", "DividerStatus", "FloatArray"]

FloatArray = NDArray[np.float64]
