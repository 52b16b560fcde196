"""``contact``: Holm contact resistance of the two electrode contacts (eq. 10-12).

Each contact is R_con = (rho1 + rho2)/4 sqrt(pi H / F), so the pair adds k / sqrt(F) ohm with
k = (rho1 + rho2)/2 sqrt(pi H) (ohm N^0.5); F d(k/sqrt F)/dF = -k / (2 sqrt F). The contact
is open at rest: F <= 0 gives +inf. The null variant adds 0 ohm.
"""

from __future__ import annotations

from typing import ClassVar

from ..params import ChannelParams
from ..physics import contact_coefficient_ohm_sqrt_n
from .base import SeriesTerm, zeros_like


class Contact(SeriesTerm):
    effect: ClassVar[str] = "contact"
    description: ClassVar[str] = "Holm contact resistance of the two electrodes (eq. 10-12)"
    parameters: ClassVar[tuple[str, ...]] = ("rho2_ohm_m",)

    def __init__(self, params: ChannelParams) -> None:
        super().__init__(params)
        self.coefficient = contact_coefficient_ohm_sqrt_n(
            params.rho1_ohm_m, params.rho2_ohm_m, params.hardness_pa
        )


class NoContact(SeriesTerm):
    """``contact`` switched off: a series term of 0 ohm (a sibling of ``Contact``)."""

    effect: ClassVar[str] = Contact.effect
    active: ClassVar[bool] = False
    description: ClassVar[str] = Contact.description
    parameters: ClassVar[tuple[str, ...]] = Contact.parameters

    def __init__(self, params: ChannelParams) -> None:
        super().__init__(params)
        self.coefficient = zeros_like(params)
