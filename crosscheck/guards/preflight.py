"""Checks of a run's inputs before any work starts: a model the tolerance policy can judge, a state inside the range
of double precision, output paths that can be written.

A model can be well formed (``cases.build.build_model`` accepts it) and still be outside what the gate can judge:

* **Magnitudes.** Every mass, length (placements, COM and task offsets, constraint geometry), inertia, gravity,
  coupling ratio and state entry must lie below :data:`LIMITS`. The backends and the tolerance policy form products
  of up to about ten model quantities (``m L^2 qd^2`` squared in a norm, ``cond(M)`` times a scale); with each factor
  below 1e12 (1e36 for an inertia, a mass times a length squared) they stay far below the double range (1e308), so
  nothing overflows to inf and no bound turns into NaN. From below, a non-zero mass is at least :data:`MIN_MASS`
  and a model with any length at all reaches at least :data:`MIN_REACH` (underflow; the 1 m floors of the policy).
* **A regular mass matrix.** The gate's error bounds are first order in the rounding of M
(``crosscheck.core.tolerance``): they hold while ``n eps cond(M)`` is small. A model whose M is singular at every
configuration (a point mass on
  a joint axis with no rotational inertia about it; a mass 1e-13 times the others) has no acceleration to compare:
  every backend is right to fail on it. :func:`check_model` evaluates M (the reference's CRBA on the model's own
  data) at :data:`PROBES` configurations and refuses the model when ``cond(M) >`` :func:`max_cond_m` at all of them,
  naming the joint velocity that carries no kinetic energy. A singular configuration of a regular model (a
  measure-zero set) is the gate's BREAKDOWN, not a bad model.

Output paths (:func:`claim_output`, :func:`claim_directory`) are checked by writing them before the run, so an
unwritable path fails in one line at once and not after the whole run, and no earlier report survives a failed run.

Each problem is a :class:`PreflightError`: the command line reports it in one line with exit code 2.
"""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

import numpy as np

from cases import configuration
from cases.model import Model
from crosscheck.references.pinocchio.kinematics import mass_matrix

EPS = float(np.finfo(float).eps)

#: Largest magnitude of each kind of quantity (SI units; module docstring). A ``ratio`` is a coupling coefficient.
LIMITS = {"mass": 1e12, "length": 1e12, "inertia": 1e36, "gravity": 1e12, "state": 1e12, "ratio": 1e12}
#: Smallest non-zero mass: a model whose masses are all 1e-300 kg has a mass matrix of subnormal numbers, and its
#: constraint solve (``Jc M^-1 Jc^T`` ~ 1e300) loses every digit; a zero mass is a massless body, which is fine.
MIN_MASS = 1e-12
#: Smallest reach (largest placement or COM offset) of a model with any length at all: the gate's length floors and
#: its frame moves are of 1 m (``Model.length_scale``, ``crosscheck.checks.frames``), so a model 1e-100 m long drowns in
#: the rounding of its world positions (the operational-space Cholesky fails on it); 1e-6 m and 1e-9 m still pass.
MIN_REACH = 1e-6
#: Constraint fields that are unit directions or names, not magnitudes.
_NOT_MAGNITUDES = {"name", "body", "body_a", "body_b", "joints", "directions", "normals", "plane"}

#: Configurations at which M is probed: q = 0 and this many more, drawn from a fixed generator.
PROBES = 4


class PreflightError(ValueError):
    """An input the run cannot judge (the message says what is wrong and what is valid)."""


def _too_large(where: str, kind: str, values) -> list[str]:
    values = np.abs(np.asarray(values, dtype=float)).reshape(-1)
    if values.size and values.max() > LIMITS[kind]:
        return [f"{where} has magnitude {values.max():.3g}, above the {kind} limit {LIMITS[kind]:.0e} where the "
                "tolerance policy holds in double precision"]
    return []


def _magnitudes(model: Model) -> list[str]:
    problems = []
    for b in model.bodies:
        where = f"body '{b.name}'"
        problems += _too_large(f"{where} mass", "mass", [b.mass])
        problems += _too_large(f"{where} centre of mass", "length", b.com)
        problems += _too_large(f"{where} joint placement translation", "length", b.translation)
        problems += _too_large(f"{where} inertia", "inertia", b.inertia)
        problems += _too_large(f"{where} armature", "inertia", [b.armature])
    for tp in model.task_points:
        problems += _too_large(f"task point '{tp.name}' offset", "length", tp.offset)
    problems += _too_large("gravity", "gravity", model.gravity)
    for c in model.constraints:
        for f in dataclasses.fields(c):
            if f.name not in _NOT_MAGNITUDES:
                kind = "ratio" if f.name == "coefficients" else "length"
                problems += _too_large(f"constraint '{c.name}' {f.name}", kind, getattr(c, f.name))
    reach = max(float(np.abs(np.concatenate([b.translation, b.com])).max()) for b in model.bodies)
    if 0.0 < reach < MIN_REACH:
        problems.append(f"the model's longest placement or COM offset is {reach:.3g} m, below {MIN_REACH:.0e} m: its "
                        "geometry drowns in the rounding of 1 m world positions (the gate's frame moves); express "
                        "lengths in a smaller unit")
    light = [f"'{b.name}' ({b.mass:.3g} kg)" for b in model.bodies if 0.0 < b.mass < MIN_MASS]
    if light:
        problems.append(f"bodies {', '.join(light)} are lighter than {MIN_MASS:.0e} kg, where the mass matrix and "
                        "the constraint solve lose their digits to underflow; give a mass of at least that, or "
                        "0 for a massless body")
    return problems


def max_cond_m(n: int) -> float:
    """The largest cond(M) the first-order bounds hold for: ``n eps cond(M) <= 1e-3``."""
    return 1e-3 / (n * EPS)


def _probe_configurations(model: Model) -> list[np.ndarray]:
    rng = np.random.default_rng(20261125)
    return [configuration.neutral(model)] + [configuration.random_configuration(model, rng, np.pi, model.length_scale)
                                             for _ in range(PROBES - 1)]


def _singular_everywhere(model: Model) -> str | None:
    """None when M is regular at some probe configuration; else what is wrong, with the null direction."""
    worst = None
    for q in _probe_configurations(model):
        M = mass_matrix(model, q)
        w, V = np.linalg.eigh(M)
        cond = w[-1] / w[0] if w[0] > 0.0 else np.inf
        if cond <= max_cond_m(model.n):
            return None
        worst = (q, w, V[:, 0]) if worst is None else worst
    q, w, null = worst
    joints = [f"{name} {v:+.3g}" for name, v in zip(model.velocity_labels, null) if abs(v) > 1e-3]
    return (f"the mass matrix is singular at every probed configuration (cond(M) > {max_cond_m(model.n):.2g}, the "
            f"limit where the tolerance policy's first-order bounds hold; at q = 0 its eigenvalues are "
            f"{np.array2string(w, precision=3)}): the joint velocity ({', '.join(joints)}) moves no mass or "
            "almost none. A point mass on a joint axis needs a rotational inertia about it, and masses may not "
            "differ by more than about 1e12")


def check_model(model: Model) -> None:
    """Raise :class:`PreflightError` listing every reason the gate cannot judge ``model`` (module docstring)."""
    problems = _magnitudes(model)
    if not problems:
        singular = _singular_everywhere(model)
        problems += [singular] if singular else []
    if problems:
        raise PreflightError(f"model '{model.name}' cannot be judged: " + "; ".join(problems))


def check_vector(label: str, values: np.ndarray) -> None:
    """A state or input vector given by the user: finite and below the ``state`` limit."""
    values = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(values)):
        raise PreflightError(f"--{label} has non-finite entries: {values.tolist()}")
    if values.size and np.abs(values).max() > LIMITS["state"]:
        raise PreflightError(f"--{label} has an entry of magnitude {np.abs(values).max():.3g}; entries must be at "
                             f"most {LIMITS['state']:.0e} (beyond that the dynamics overflow double precision)")


def claim_output(path: str | Path, label: str, placeholder: str) -> Path:
    """Make sure the run can write ``path`` before it starts: create its directory and write ``placeholder`` there
    (so a report left from an earlier run never survives a run that then fails). A directory, a parent that is a
    file, or an unwritable place is a :class:`PreflightError` naming the option."""
    path = Path(path)
    if path.is_dir():
        raise PreflightError(f"--{label} {path} is a directory; give a file path, e.g. {path / 'report.md'}")
    blocking = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        raise PreflightError(f"--{label} {path} cannot be written: {blocking} is a file, not a directory")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(placeholder)
    except OSError as exc:
        raise PreflightError(f"--{label} {path} cannot be written: {exc.strerror or exc}") from None
    return path


def claim_directory(path: str | Path, label: str) -> Path:
    """Make sure the run can write files in the directory ``path`` before it starts (created if missing); a file in
    its place or an unwritable place is a :class:`PreflightError` naming the option."""
    path = Path(path)
    blocking = next((p for p in (path, *path.parents) if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        raise PreflightError(f"--{label} {path} cannot be a report directory: {blocking} is a file")
    try:
        path.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
    except OSError as exc:
        raise PreflightError(f"--{label} {path} cannot be written: {exc.strerror or exc}") from None
    return path
