"""A root strain gauge whose calibration is off by a factor: a sensor gain to identify."""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx

from jaxflex.effects._base import Effect, Structure
from jaxflex.parameters import ParameterSpec, Params


class StrainGaugeGain(Effect):
    """Scales the root strain the model outputs: ``root_strain ← (1 + e_sg) · root_strain``.

    A gauge's reading is ``gain·strain``; its gain comes from a calibration (gauge factor,
    bridge and amplifier gains, or a vendor's factor to a deflection angle) and from where the
    gauge sits (the strain falls off linearly from the clamp), both often known to ±20 %.
    ``1 + e_sg`` is the ratio of the true gain to the one assumed (``e_sg`` its relative error,
    of either sign). The simulator reads the root
    strain through the row ``root_curvature`` of the structure, which nothing else uses, so
    scaling that row scales this output alone and leaves the motion untouched.
    """

    name: ClassVar[str] = "strain_gauge_gain"
    parameters: ClassVar[tuple[ParameterSpec, ...]] = (
        ParameterSpec(
            "e_sg",
            "1",
            lower=-0.5,
            upper=1.0,
            reference=0.0,
            description="relative error of the root strain gauge's assumed gain",
            log_scale=False,
            null=0.0,
        ),
    )
    description: ClassVar[str] = (
        "The root strain gauge reads a fixed multiple of the true strain: its calibration "
        "factor, or its distance from the clamp, is not what the arm file says. The arm moves "
        "as before; only the reading is scaled."
    )
    signature: ClassVar[str] = (
        "root-strain residual proportional to the root strain itself (same shape and phase, "
        "every frequency alike) while the joint-angle residual shows nothing; frequencies "
        "unchanged"
    )

    def structure(self, structure: Structure, params: Params) -> Structure:
        return eqx.tree_at(
            lambda s: s.root_curvature, structure, (1.0 + params["e_sg"]) * structure.root_curvature
        )
