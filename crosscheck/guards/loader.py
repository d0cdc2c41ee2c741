"""Loader findings: a model loaded from a file, checked against that file read apart from the loader, when its case is
set up (before any dynamics runs).

The loaders (``cases/urdf.py``, ``cases/mjcf.py``) convert a file through Pinocchio's parsers, and the Pinocchio
reference reads the file through the same parser (``cases.urdf.read_file``): what the parser misreads, every voter
shares, and the vote passes. What the vote cannot see is checked here, against the file read again by the format's
rules, without the loader:

* a **URDF** file: every body of the converted model, field by field, against the second reading of
  ``crosscheck.guards.file_reading`` (mass, COM, inertia, joint placement, axis, type, parent, limits, ``<mimic>``
  couplings; the fixed-joint merge and the base), paired by link name, to rounding;
* an **MJCF** file: the joint limits (``crosscheck.guards.file_limits``, paired through the Pinocchio reference's
  joint map, to :data:`LIMIT_ROUNDING`). A second reading of an MJCF file's bodies (its ``<inertial>``, ``pos`` and
  ``quat``/``euler`` frames, default classes and ``<compiler>`` rules) belongs here, beside the URDF one; it is not
  written yet, so an MJCF model's masses, inertias and placements rest on Pinocchio's MJCF parser alone.

Each difference is a :class:`~crosscheck.guards.file_reading.Finding` (``loader finding: link 'forearm' inertia: the
file says ..., the loaded model has ... (max difference ...)``). The gate computes :func:`check` once per case, right
after building its model (``crosscheck.engine.run``); a finding fails the case (``CaseOutcome.failed``), and the
report, the terminal and JUnit list it. A model without a file (a built-in case, a fuzz model) has nothing to check.
A URDF file the second reading cannot read by the format's rules, though the loader read it, is a finding too: the
model would otherwise go unchecked. (An MJCF file whose limits cannot be read or paired apart from the loader is
reported as such in the line of :meth:`LoaderCheck.line`, and the coverage says the same of the limits it measured
against: as before this module, no finding.)
"""

from __future__ import annotations

from dataclasses import dataclass

from cases.model import Model
from crosscheck.guards import file_limits, file_reading
from crosscheck.guards.file_reading import Finding

#: Converted MJCF limits that differ from the file's by more than this (relative to the bound, at least absolute) are
#: a loader finding: a hinge's degrees are converted by both readings, in different orders of operations.
LIMIT_ROUNDING = 1e-9


@dataclass(frozen=True)
class LoaderCheck:
    """What :func:`check` compared for one model: the file (``kind``, ``path``), ``what`` was compared (in words, for
    the report), ``bodies`` the number of bodies compared and the ``findings``."""

    kind: str
    path: str
    what: str
    bodies: int
    findings: tuple[Finding, ...]

    def line(self) -> str:
        """One line for the report: what was read and what it found."""
        found = (f"{len(self.findings)} loader finding(s)" if self.findings else "no finding")
        return f"{self.what} of {self.bodies} bodies against the {self.kind.upper()} file {self.path}: {found}"


def check(model: Model) -> LoaderCheck | None:
    """``model`` against its file read apart from the loader (module doc); None for a model without a file."""
    source = model.source
    if source is None:
        return None
    if source.kind == "urdf":
        what = "every field (mass, COM, inertia, placement, axis, type, parent, limits, mimic)"
        try:
            reading = file_reading.read_urdf(source.path, source.root)
        except (OSError, ValueError) as exc:
            return LoaderCheck("urdf", source.path, what, 0, (_unread(model, exc),))
        return LoaderCheck("urdf", source.path, what, len(model.bodies), tuple(file_reading.compare(model, reading)))
    read = file_limits.read(model)
    if read.limits is None:
        return LoaderCheck(source.kind, source.path,
                           f"the joint limits (not read apart from the loader: {read.reason})", 0, ())
    return LoaderCheck(source.kind, source.path, "the joint limits", len(model.bodies), tuple(_limits(model, read)))


def _unread(model: Model, exc: Exception) -> Finding:
    reason = " ".join(str(exc).split())
    return Finding(model.bodies[0].name if model.bodies else "-", "file",
                   f"nothing this second reading can read by the URDF rules ({reason})",
                   f"{len(model.bodies)} bodies, unchecked")


def _same(ours, theirs) -> tuple[bool, float, float]:
    """Whether two limits agree to :data:`LIMIT_ROUNDING`, the largest difference and its tolerance."""
    if ours is None or theirs is None:
        return ours is None and theirs is None, float("inf"), 0.0
    difference = max(abs(a - b) for a, b in zip(ours, theirs))
    tolerance = LIMIT_ROUNDING * max(1.0, *(abs(b) for b in theirs))
    return difference <= tolerance, difference, tolerance


def _pair(limits) -> str:
    return "no limits" if limits is None else f"[{limits[0]:.10g}, {limits[1]:.10g}]"


def _limits(model: Model, read: file_limits.FileLimits) -> list[Finding]:
    """The model's joint limits against the file's as ``crosscheck.guards.file_limits`` read them."""
    found = []
    for body, theirs, joint in zip(model.bodies, read.limits, read.joints):
        same, difference, tolerance = _same(body.limits, theirs)
        if not same:
            found.append(Finding(body.name, f"limits (joint '{joint}', {body.joint})", _pair(theirs),
                                 _pair(body.limits), difference, tolerance))
    return found
