"""Closed forms of the built-in cases, and the gate's voter ``closed_form``.

The five formalisms and the Pinocchio reference all read the same :class:`~cases.model.Model`: a bug in a case
factory or in the model language (an inertia rotated the wrong way, a length read from the wrong parameter) moves all
six together, and their vote cannot see it. A closed form does not read the model: it is bound to the case BY NAME
and computes every quantity from the case's TYPED PARAMETERS (``cases.parameters``) and the state alone, from
equations typed in from the article or derived by hand in the docstrings below. The only things it reads off the
model are its shape (coordinates n, inputs m, constraint rows k), its name and its armature (``Body.armature``, a
rotor's inertia on M's diagonal), to refuse a model that is not the case it was written for
(:class:`ClosedFormMismatch`, an error of the voter: a failure of the gate, never a silent NOT COMPARED): the armature
is compared with the one its parameters give (the pendulums: ``a1``, ``a2``, ``a``; :func:`rotor_inertia`), and a
closed form without armature refuses a model that has some, rather than drop it from M.

    >>> from crosscheck.engine import evaluation
    >>> from crosscheck.references import closed_forms
    >>> voter = closed_forms.voter("double_pendulum", {"l2": "0.7"})     # None where no closed form exists
    >>> outcome = evaluation.evaluate(cases.load("double_pendulum", l2="0.7"), state, [*backends, voter])

Cases and their equations (:func:`coverage` says the same for one case):

=============================  =====================================================================================
double_pendulum                article section 3: eqs. (4)-(9), point masses plus planar disk inertias I1, I2, the
                               joints' armature a1, a2 (:func:`rotor_inertia`)
n_link_pendulum                the Lagrangian in absolute angles (:func:`chain_terms`) mapped to relative angles, the
                               joints' armature a
acrobot                        Spong's equations, angles from hanging down (:func:`acrobot_terms`), armature a1, a2
double_pendulum_circle         article 5.6: eqs. (12)-(17) with one circle row (:func:`circle_terms`)
cartesian_pendulum             the multiplier of eqs. (12)-(13) solved by hand (:func:`cartesian_lam`)
double_pendulum_absolute_loop  the double pendulum's accelerations in the loop's coordinates, its multipliers the pins'
                               forces by Newton's second law (:func:`pin_forces`)
rotor                          one body on a tilted revolute joint (:func:`rotor_terms`)
inclined_slider                a point mass on a tilted prismatic joint (:func:`slider_terms`)
spherical_pendulum             a ball on two perpendicular revolute joints (:func:`spherical_terms`)
four_bar                       three uniform rods (:func:`rod_chain_terms`: a rod is three point masses) in absolute
                               angles mapped to relative (:func:`four_bar_terms`), the loop's two rows
                               (:func:`four_bar_loop`); minimum-norm multipliers at the change points
slider_crank                   two rods and a point-mass slider (:func:`slider_crank_terms`), the wrist pin's two rows
                               (:func:`wrist_pin`)
double_pendulum_rail           eqs. (4)-(8) with the tip on a straight rail, a ``PointOnLine`` row (:func:`rail_terms`)
geared_pendulums               two rods coupled by a gear, a ``JointCoupling`` row (:func:`gear_terms`,
                               :func:`gear_constraint`)
free_body                      Newton's and Euler's equations in the body frame (:func:`free_body_terms`)
knife_edge                     the Chaplygin sleigh: Newton and Euler along and across the runner, a ``KnifeEdge``
                               (Pfaffian) row (:func:`sleigh_terms`, :func:`sleigh_motion`)
rolling_disk                   the classical rolling disk (Neimark-Fufaev, Bloch 1.4): the centre's velocity and the
                               angular velocity in the heading frame, the contact's two ``RollingContact`` rows
                               (:func:`disk_terms`, :func:`disk_center`)
double_pendulum_tip_force      eqs. (4)-(9) with ``tau_ext = J^T f`` of a world force at the tip (:func:`tip_force`)
double_pendulum_spring         eqs. (4)-(9) with a tip spring and a body-frame wrench on link 2 (:func:`tip_spring`)
differential_drive             Newton-Euler of chassis and wheels in the forward speed and the turning rate, the two
                               rolling-direction rows and the axle's row, the payload's ``tau_ext = J^T F``
                               (:func:`drive_terms`, :func:`drive_motion`, :func:`drive_load`)
=============================  =====================================================================================

Each supplies drift, ctrl and total (eq. 9; eqs. 14, 15, 17 with constraints; ctrl ``B_c B u`` computed directly),
the control power, the kinetic energy, the task drift and the task inertia (eq. 22, with ``conditions
["task_inertia"]``), and on the constrained cases lam, lam_drift, the constraint kinematics, forces and power. The
joint loads are not supplied (UNSUPPORTED: "not supplied by" in a report). cond(M), ``accel_scale`` and the
constraint conditions are computed here, from these closed forms, by the definitions of ``Split.accel_scale``,
``lam_scale`` and the conditions (no numeric helper of the harness is used). Where S = Jc M^-1 Jc^T is singular (the
four-bar's change points) a closed form follows the backends' rule for redundant rows (:class:`Rule`, with the
model's length and inertia scales typed in from the factory): the minimum-norm multipliers and the same
``constraint``, ``constraint_kept`` and ``constraint_consistency`` conditions (:func:`constrained`).

The double-pendulum formulas (:func:`article_M`, :func:`article_Cqd`, :func:`article_g`, :func:`pendulum_terms`)
evaluate in double precision or, with ``lib=MPMATH``, in mpmath (:func:`pendulum_terms_mp`): one typing of eqs.
(6)-(8) for both. The tests' ``tests/closed_forms.py`` re-exports what the tests use of this package.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Callable, Mapping

import numpy as np

import cases
from crosscheck.references.closed_forms.by_case import (absolute_loop_rule, acrobot, cartesian_pendulum, cartesian_rule,
                                                        differential_drive, disk_rule, double_pendulum,
                                                        double_pendulum_absolute_loop, double_pendulum_circle,
                                                        double_pendulum_rail, double_pendulum_rule,
                                                        double_pendulum_spring, double_pendulum_tip_force, drive_rule,
                                                        four_bar, four_bar_rule, free_body, gear_rule, geared_pendulums,
                                                        inclined_slider, knife_edge, n_link_pendulum, rolling_disk,
                                                        rotor, sleigh_rule, slider_crank, slider_crank_rule,
                                                        spherical_pendulum)
from crosscheck.references.closed_forms.constrained import Rule
from formalisms.interface import check_state, Formalism, Split


class ClosedFormMismatch(ValueError):
    """The model given to a closed form is not the case and parameters it was bound to (another case's model, or a
    shape that the parameters do not give): the message names the case, its parameters and what does not match."""


# ------------------------------------------------------------------------------------------------- the voter

UNCONSTRAINED = ("drift", "ctrl", "total", "additivity", "power_ctrl", "task_drift", "kinetic_energy", "task_inertia")
CONSTRAINED = ("lam", "lam_drift", "constraint_force", "constraint_force_drift", "power_constr",
               "power_constr_per_coord", "admissibility_drift", "admissibility_total", "constraint_value",
               "constraint_velocity", "constraint_jacobian", "constraint_bias")
LOADED = ("external_force", "power_ext")


@dataclass(frozen=True)
class ClosedForm:
    """One case's closed form: where its equations come from, the shape (n, m, k) its parameters give, its split
    from the typed parameters and a state, and (constrained cases) the scales of the backends' rule for redundant
    rows from the typed parameters (:class:`Rule`; equal to the model's ``length_scale`` and ``inertia_scale``)."""

    source: str
    shape: Callable[[dict], tuple[int, int, int]]
    split: Callable[[dict, np.ndarray, np.ndarray, np.ndarray], Split]
    rule: Callable[[dict], Rule] | None = None
    loaded: bool = False
    #: The armature per velocity its parameters give (``Body.armature``, on M's diagonal), for a closed form that
    #: adds the joints' rotors to M; None: it has none, and refuses a model with armature (:func:`_checked_split`).
    armature: Callable[[dict], np.ndarray] | None = None

    def supplies(self, params: dict) -> tuple[str, ...]:
        """The compared quantities it supplies (the joint loads are not among them)."""
        return UNCONSTRAINED + (CONSTRAINED if self.shape(params)[2] else ()) + (LOADED if self.loaded else ())


CLOSED_FORMS: dict[str, ClosedForm] = {
    "double_pendulum": ClosedForm("article section 3, eqs. (4)-(9), with planar disk inertias I1, I2 and the joints' "
                                  "armature a1, a2", lambda p: (2, 2, 0), double_pendulum,
                                  armature=lambda p: np.array([p["a1"], p["a2"]], dtype=float)),
    "n_link_pendulum": ClosedForm("the Lagrangian of n point masses in absolute angles, mapped to relative angles, "
                                  "with the joints' armature a", lambda p: (p["n"], p["n"], 0), n_link_pendulum,
                                  armature=lambda p: np.full(p["n"], p["a"], dtype=float)),
    "acrobot": ClosedForm("Spong's acrobot equations, angles from hanging down, with the joints' armature a1, a2",
                          lambda p: (2, 1, 0), acrobot, armature=lambda p: np.array([p["a1"], p["a2"]], dtype=float)),
    "double_pendulum_circle": ClosedForm("article 5.6, eqs. (4)-(8), (12)-(17), one circle row",
                                         lambda p: (2, 2, 1), double_pendulum_circle, double_pendulum_rule),
    "cartesian_pendulum": ClosedForm("the multiplier of eqs. (12)-(13) by hand, M = m I",
                                     lambda p: (2, 2, 1), cartesian_pendulum, cartesian_rule),
    "double_pendulum_absolute_loop": ClosedForm(
        "the double pendulum's eqs. (4)-(9) mapped to the loop, multipliers the pins' forces (Newton)",
        lambda p: (6, 2, 4), double_pendulum_absolute_loop, absolute_loop_rule),
    "rotor": ClosedForm("one rigid body on a tilted revolute joint, by hand", lambda p: (1, 1, 0), rotor),
    "inclined_slider": ClosedForm("a point mass on a tilted prismatic joint, by hand", lambda p: (1, 1, 0),
                                  inclined_slider),
    "spherical_pendulum": ClosedForm("a ball on two perpendicular revolute joints, by hand", lambda p: (2, 2, 0),
                                     spherical_pendulum),
    "four_bar": ClosedForm("three uniform rods by hand (absolute angles mapped to relative), the loop's two rows, "
                           "eqs. (12)-(17) with minimum-norm multipliers at the change points",
                           lambda p: (3, 3, 2), four_bar, four_bar_rule),
    "slider_crank": ClosedForm("two uniform rods and a point-mass slider by hand, the wrist pin's two rows, "
                               "eqs. (12)-(17)", lambda p: (3, 3, 2), slider_crank, slider_crank_rule),
    "double_pendulum_rail": ClosedForm("article section 3, eqs. (4)-(8), with the tip's PointOnLine row, "
                                       "eqs. (12)-(17)", lambda p: (2, 2, 1), double_pendulum_rail,
                                       double_pendulum_rule),
    "free_body": ClosedForm("Newton's and Euler's equations of a free rigid body in its own frame, by hand",
                            lambda p: (6, 6, 0), free_body),
    "knife_edge": ClosedForm("the Chaplygin sleigh by hand: Newton and Euler along and across the runner, the knife "
                             "edge's Pfaffian row, eqs. (12)-(17)", lambda p: (3, 3, 1), knife_edge, sleigh_rule),
    "rolling_disk": ClosedForm("the rolling disk by hand (Neimark-Fufaev, Bloch 1.4): the centre's velocity and the "
                               "angular velocity in the heading frame, the contact's two Pfaffian rows, eqs. (12)-(17)",
                               lambda p: (5, 5, 2), rolling_disk, disk_rule),
    "geared_pendulums": ClosedForm("two uniform rods by hand coupled by a JointCoupling gear, eqs. (12)-(17)",
                                   lambda p: (2, 2, 1), geared_pendulums, gear_rule),
    "double_pendulum_tip_force": ClosedForm("article section 3, eqs. (4)-(9), with tau_ext = J^T f of the tip force "
                                            "(eq. 12, 14)", lambda p: (2, 2, 0), double_pendulum_tip_force,
                                            loaded=True),
    "double_pendulum_spring": ClosedForm("article section 3, eqs. (4)-(9), with tau_ext of the tip spring and the "
                                         "body-frame wrench by hand (eq. 12, 14)", lambda p: (2, 2, 0),
                                         double_pendulum_spring, loaded=True),
    "differential_drive": ClosedForm("Newton-Euler of chassis and wheels by hand in the forward speed and the turning "
                                     "rate (the wheels' spin inertia), the rolling-direction and axle rows, tau_ext = "
                                     "J^T F of the payload, eqs. (12)-(17)", lambda p: (5, 2, 3), differential_drive,
                                     drive_rule, loaded=True),
}


def _describe(params: dict) -> str:
    return ", ".join(f"{k}={v!r}" for k, v in params.items())


def _checked_split(case: str, form: ClosedForm, params: dict, model, q, qd, u) -> Split:
    """The closed form's split at (q, qd, u) after checking that ``model`` is the case it is bound to: its name (a
    moved scene's ``case@frame`` included) and its shape (n, m, k) from the parameters; else ClosedFormMismatch."""
    n, m, k = form.shape(params)
    shapes = (("the number of coordinates n", model.n, n), ("the number of inputs m", model.m, m),
              ("the number of constraint rows k", model.k, k))
    problems = [f"{label} is {got}, the closed form's is {want}" for label, got, want in shapes if got != want]
    if model.name.split("@")[0] != case:
        problems.insert(0, f"the model is named '{model.name}', not '{case}'")
    if not problems:
        problems += _armature_mismatch(form, params, model)
    if problems:
        raise ClosedFormMismatch(f"the closed form of case '{case}' ({_describe(params)}) does not match the model it "
                                 f"was given: {'; '.join(problems)}")
    q, qd, u = check_state(model, q, qd, u)
    return form.split(params, q, qd, u)


def _armature_mismatch(form: ClosedForm, params: dict, model) -> list[str]:
    """The armature (``Body.armature``) is part of M, so a closed form that does not add it cannot vote on a model
    that has it (it would silently drop it), and one that does must add the model's: compared, not used."""
    armature = np.asarray(model.armature_vector, dtype=float)
    if form.armature is None:
        return [] if not armature.any() else [
            f"the model has armature {armature.tolist()} (a rotor's inertia on M's diagonal), which this closed form "
            "does not add to M"]
    expected = np.asarray(form.armature(params), dtype=float)
    if expected.shape == armature.shape and np.array_equal(expected, armature):
        return []
    return [f"the model's armature is {armature.tolist()}, the closed form's (from its parameters) {expected.tolist()}"]


def voter(case: str, params: Mapping[str, object] | None = None) -> Formalism | None:
    """The gate's voter ``closed_form`` for case ``case`` built with ``params`` (numbers or CLI strings, converted as
    ``cases.load`` converts them; CaseError for an unknown parameter), or None when the case has no closed form. Its
    ``split(model, q, qd, u)`` computes from the typed parameters alone and raises :class:`ClosedFormMismatch` for a
    model that is not that case with those parameters."""
    form = CLOSED_FORMS.get(case)
    if form is None:
        return None
    typed = cases.parameters(case, **dict(params or {}))
    return Formalism("closed_form", f"closed form of {case}: {form.source}", partial(_checked_split, case, form, typed))


def coverage(case: str, params: Mapping[str, object] | None = None) -> str:
    """For a report's line on ``case`` (the caller names the case): the closed form that votes on it with ``params``,
    the typed parameters it is bound to and the quantities it supplies, or "none" and, for a case loaded from a model
    file (``cases.model_file``), that its reference is built from the file, else the cases that have one."""
    form = CLOSED_FORMS.get(case)
    if form is None and cases.model_file(case) is not None:
        return f"none (loaded from the model file {cases.model_file(case)}; its reference is built from the file)"
    if form is None:
        return f"none (closed forms exist for {', '.join(CLOSED_FORMS)})"
    typed = cases.parameters(case, **dict(params or {}))
    return (f"{form.source}; bound to {_describe(typed)}; supplies {', '.join(form.supplies(typed))} (not the joint "
            "loads)")
