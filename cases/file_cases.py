"""Built-in cases loaded from small model files shipped with the package (``cases/files/``), one per loader path.

The other built-in cases are built in code (``cases.factories`` and its siblings) or loaded from example-robot-data's
robots (``panda``, ``solo12``), none of which has a mimic multiplier other than 1, a continuous joint, an MJCF
file or joint armature. These cases put every path of the loaders (``cases.urdf``, ``cases.mjcf``) in every default gate run: each is
loaded through the loader, so its model carries the file as its ``source`` and the Pinocchio reference is built
from the file itself (``crosscheck.references.pinocchio.build``): a conversion fault moves the five formalisms and
not the reference. They have no closed form; the file-built reference is their independent voter. They are built-in
cases like the others: the gate's ``CaseSpec(name)`` carries no path, so ``--case NAME`` (a report's reproduce
command, ``crosscheck eval --case NAME``) builds them through this registry wherever the package is installed, and
the file is found next to this module (:data:`FILES`).

=================  ===================================  ===========================================================
case               file                                 loader paths
=================  ===================================  ===========================================================
urdf_gripper       ``cases/files/gripper.urdf``         a continuous joint (about x, unlimited); a prismatic and
                                                        two revolute joints with limits; a ``<mimic>`` with
                                                        multiplier -0.8 and offset 0.05 (a ``JointCoupling`` row
                                                        with an offset); a link welded by a fixed joint with a
                                                        rotated, offset origin (its inertia merged into its
                                                        parent's); every ``<inertial>`` frame rotated (rpy)
mjcf_floating      ``cases/files/floating.xml``         a ``<freejoint/>``; a hinge with a range in degrees (the
                                                        default ``<compiler angle="degree">``); a body turned by
                                                        ``euler`` (degrees); a body without a joint (welded: its
                                                        inertia merged into its parent's); ``<inertial
                                                        fullinertia>`` and ``<inertial diaginertia quat>``
mjcf_ball_slide    ``cases/files/ball_slide.xml``       a ball joint; a slide with a range (metres, which
                                                        Pinocchio's parser reads as degrees and the loader undoes);
                                                        a body turned by ``quat``, one by ``euler``; ``diaginertia
                                                        quat`` and ``fullinertia``
mjcf_armature      ``cases/files/armature_arm.xml``     joint ``armature`` (rotor inertia on M's diagonal): on a
                                                        hinge itself, from a ``<default>`` class, a class's value
                                                        overridden on the joint, on a slide; a different value on
                                                        every joint; ranges in degrees and metres
=================  ===================================  ===========================================================

Each file is small (2 to 4 joints) because every default gate run evaluates it at every state with every check; the
masses and inertias are physical (principal moments satisfying the triangle inequality), so a model finding would
be a loader fault. The files say in a comment what each element is for. ``tests/model/test_file_cases.py`` checks
each path is exercised and that a fault injected into it fails the gate.
"""

from __future__ import annotations

from pathlib import Path

from cases.factories import loaded_from, register
from cases.model import Model

#: The folder of the shipped model files (package data: ``pyproject.toml``, ``[tool.setuptools.package-data]``).
FILES = Path(__file__).resolve().parent / "files"


def file_path(name: str) -> Path:
    """The shipped model file ``name`` (e.g. ``"gripper.urdf"``) in :data:`FILES`; FileNotFoundError saying the
    installation lacks the package data where it is missing."""
    path = FILES / name
    if not path.is_file():
        raise FileNotFoundError(f"crosscheck's model file '{path}' is missing: the installation lacks the package "
                                "data of cases/files (reinstall crosscheck)")
    return path


@register
@loaded_from("cases/files/gripper.urdf, shipped with crosscheck")
def urdf_gripper() -> Model:
    """A wrist and gripper from the shipped URDF cases/files/gripper.urdf: continuous, limited, fixed and mimic joints.

    A continuous roll, a limited slide, a palm welded by a fixed joint (merged), two limited fingers, the second a
    ``<mimic>`` of the first with multiplier -0.8 and offset 0.05. 4 coordinates (Pinocchio's joint order:
    wrist_roll, extend, finger_left, finger_right), one ``JointCoupling`` row ``mimic:finger_right``, every joint
    driven; the base link welded to the world. Module docstring: what each element of the file exercises.
    """
    from cases.urdf import from_urdf

    return from_urdf(file_path("gripper.urdf"), name="urdf_gripper", base="fixed")


@register
@loaded_from("cases/files/floating.xml, shipped with crosscheck")
def mjcf_floating() -> Model:
    """A floating torso and arm from the shipped MJCF cases/files/floating.xml: a free joint, a hinge ranged in degrees.

    The arm's body is turned by ``euler`` and carries a welded hand (no joint: merged); the torso's inertia is a
    ``fullinertia``, the arm's a ``diaginertia`` turned by a ``quat``. nq 8, nv 7; only the hinge is driven (B has one
    column). Module docstring: what each element of the file exercises.
    """
    from cases.mjcf import from_mjcf

    return from_mjcf(file_path("floating.xml"), name="mjcf_floating")


@register
@loaded_from("cases/files/ball_slide.xml, shipped with crosscheck")
def mjcf_ball_slide() -> Model:
    """A ball-jointed rod and sliding bob from the shipped MJCF cases/files/ball_slide.xml: a ball joint, a slide.

    The rod's body is turned by ``quat``, the bob's by ``euler``; the slide's range is in metres. nq 5, nv 4, every
    velocity driven; the pivot is welded to the world. Module docstring: what each element of the file exercises.
    """
    from cases.mjcf import from_mjcf

    return from_mjcf(file_path("ball_slide.xml"), name="mjcf_ball_slide")


@register
@loaded_from("cases/files/armature_arm.xml, shipped with crosscheck")
def mjcf_armature() -> Model:
    """A three-hinge arm with a sliding tool from the shipped MJCF cases/files/armature_arm.xml: armature on every joint.

    Armature 0.12 (shoulder, on the joint), 0.045 (upper, from the default class ``motor``), 0.02 (fore, the class's
    value overridden), 0.3 kg (tool, a slide): ``M = M_links + diag(0.12, 0.045, 0.02, 0.3)``. nq = nv = 4, every
    joint driven; the base welded to the world. Module docstring: what each element of the file exercises.
    """
    from cases.mjcf import from_mjcf

    return from_mjcf(file_path("armature_arm.xml"), name="mjcf_armature")


__all__ = ["FILES", "file_path", "mjcf_armature", "mjcf_ball_slide", "mjcf_floating", "urdf_gripper"]
