"""Find what the model is missing: score tests of candidate effects, add-and-refit, discovery.

The discovery likelihood
    Residuals are whitened per channel by the measurement noise, ``u = (y − ŷ)/σ_c``. The
    accelerometer's noise is white, so its residuals enter as they are. An encoder's
    quantisation error is bounded by ``±q/2`` but constant while the arm rests, so treating it as
    white noise would read a resting arm's rounding error as overwhelming evidence; a quantised
    channel therefore enters through the part of the residual beyond the quantisation bound,
    ``dz(u) = sign(u)·max(|u| − h, 0)`` with ``h = q/(2σ) = √3``. The statistics cost is
    ``C(θ) = Σ dz(u)²`` (white channels: ``dz(u) = u``), i.e. ``−2 log L`` up to a constant with
    the noise levels fixed (estimated once, at the start). Fits minimise ``C`` plus a small
    ``ε·Σ u²`` over the quantised samples, which keeps the angle on the measured counts.

Score (Lagrange-multiplier) test
    Every candidate effect vanishes at its null parameters, so the model *with* the effect at
    its null is the fitted model, and the gradient of ``C`` with respect to the effect's
    parameters there says whether switching it on would help — before fitting it. With the
    whitened Jacobian ``J = [J_n, J_c]`` (``n``: the fitted parameters, ``c``: the candidate's)
    and residual ``r``, partialling the nuisance parameters out (``P_n`` projects on ``J_n``;
    fitted parameters held on a bound are fixed, not nuisance):

        ``J_c⊥ = (I − P_n) J_c``,  ``g = J_c⊥ᵀ r``,  ``V = J_c⊥ᵀ J_c⊥``,  ``S = gᵀ V⁻¹ g``,

    which is ``gᵀ (I⁻¹)_cc g`` with the Gauss–Newton information ``I = JᵀJ`` (noise-whitened) —
    the drop of ``C`` one Gauss–Newton step on the candidate would give. ``S ~ χ²_k`` under the
    null. The library's nulls lie on a boundary (a mass, a delay cannot be negative): for one
    parameter the test is one-sided, ``S = max(z, 0)²`` with ``z = g/√V`` and ``p = ½ P(χ²₁ > S)``
    (the 50:50 χ̄² mixture); with several, ``χ²_k`` of the unconstrained ``S`` (valid, somewhat
    conservative). ``β̂ = V⁻¹ g`` estimates the effect's size. The quantised channel enters ``J``
    with all its samples (as if its noise were white with ``σ = q/√12``), which is conservative.
    All candidates share one Jacobian: the model is extended by every candidate at once (at
    their nulls it is still the fitted model), one forward-mode pass gives every column. That
    extended model always holds the whole library, so every call on the same records — score
    tests, refits, a discovery run — reuses one compiled function.

    A Stribeck velocity ``v_s`` is undefined under the null (``Δτ_s = 0`` switches every ``v_s``
    off): the test profiles it over :meth:`~jaxflex.effects.Stribeck.grid` — a score statistic
    per grid value, the largest kept, its p-value multiplied by the grid size (Bonferroni).
    Any effect class with a ``grid()`` is profiled the same way. ``v_s`` is a parameter without
    a null: the grid value is only where it starts, and the refits fit it with ``Δτ_s``.

The loop (:func:`discover`)
    Fit the base model; then repeat: diagnose the residuals (:mod:`jaxflex.diagnosis`), score-test
    every candidate not yet in the model (significant at ``alpha/m``, Bonferroni over the ``m``
    candidates), refit the best few (warm start, a 1-D profile of the new parameters, then
    Levenberg–Marquardt of all; where base parameters lie on a bound, having compensated the
    missing effect as far as they could, also from where the run started — the given start or, from
    scratch, the search's centre — its profile taken there), confirm each by the likelihood-ratio
    test ``LR = C₀ − C₁`` at ``alpha/m`` and a falling BIC (``C + d·ln N``), and add the one with
    the largest LR. A refit that ends on a bound of the effect's own parameters (not its null
    side) is no explanation: that bound is moved out once to the effect's physical limit
    (:meth:`~jaxflex.effects.AbstractEffect.physical_limits`; a given bound stays) and the
    candidate refitted; still on it, it is not confirmed and the next one is taken. Two
    confirmed candidates whose LRs differ by less than the χ²₁ 95 % quantile are named as
    alternatives, with what would tell them apart. The score test is local: when the misfit is
    too large for a first-order picture
    and no refitted candidate explained most of it (:data:`MIN_EXPLAINED`) while the residuals are
    not noise, each other candidate's 1-D profile (the fitted parameters re-optimised to first
    order) is scanned, and every one the scan finds is refitted. Ties are real: a delay and a
    first-order lag have the same derivative at their null; the refits tell them apart. Stop when
    no candidate is significant and confirmed. An effect is kept only if the final residuals are
    consistent with the noise, or it explained most (:data:`MIN_EXPLAINED`) of the misfit above the
    noise when it was added, or it lowered the error on held-out records (the mean over the
    channels; a real rig always keeps some misfit no candidate explains); otherwise it is
    withdrawn, and whatever the residuals still hold is reported as ``unexplained`` — where in time
    and frequency, and how large. There, with no candidate confirmed at the last step, the missing
    hub torque is mapped at the final model and, where the map says it is a function of state
    and input, its formula is refitted as one more candidate and added when confirmed and the
    held-out error falls (:mod:`jaxflex.discovery.torque_proposal`; ``torque_map=False`` turns
    it off).

Claims
    What the report says about each candidate (explains, withdrawn, not added and why, the
    ranking's order, the evidence cited) follows one stated rule per claim on named statistics:
    :data:`~jaxflex.discovery.explain.RULES`, listed in the documentation's *Physical effects*
    page.

Channels
    The records may measure any of the simulator's outputs or the rig's sensor channels
    (``channels=``, as in ``identify``; by default the rig's sensors that every record holds:
    an encoder and a root strain gauge logged as ``joint_angle`` and ``deflection_angle``).
    Residuals, noise levels, the diagnosis (its FRF from the input to the first link channel)
    and the report are per channel, each in its unit; what the records do not measure is not
    fitted.
"""

from jaxflex.discovery.candidates import (
    Candidate,
    candidate_set,
    default_candidates,
    encoder_channels,
)
from jaxflex.discovery.example import load_example
from jaxflex.discovery.explain import RULES
from jaxflex.discovery.loop import discover
from jaxflex.discovery.operations import add_effect, refit, score_tests
from jaxflex.discovery.report import Confirmation, DiscoveryFit, DiscoveryReport, Step
from jaxflex.discovery.scores import ALPHA, ScoreResult

__all__ = [
    "ALPHA",
    "RULES",
    "Candidate",
    "Confirmation",
    "DiscoveryFit",
    "DiscoveryReport",
    "ScoreResult",
    "Step",
    "add_effect",
    "candidate_set",
    "default_candidates",
    "discover",
    "encoder_channels",
    "load_example",
    "refit",
    "score_tests",
]
