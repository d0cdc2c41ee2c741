"""Issue 17's acceptance check: random floating-base URDF trees, loaded with a free root, agree with Pinocchio's
``aba`` on the same file loaded with ``JointModelFreeFlyer()``, for all five backends, to 1e-9 relative.

The trees are a held-out set: drawn here from their own seed (random links, revolute, continuous and prismatic joints
about random axes, rotated origins, rotated inertials), written as URDF text, and never seen by the backends'
own tests. The truth is Pinocchio reading the file itself, not our conversion of it."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import cases
from crosscheck import backends
from crosscheck.core import sampling

#: The held-out set: this many trees from this seed.
TREES, SEED = 6, 170017
RELATIVE = 1e-9


def _xyz(v) -> str:
    return " ".join(f"{x:.17g}" for x in v)


def _inertial(rng) -> str:
    mass = 10 ** rng.uniform(-1, 1)
    a, b = rng.uniform(0.1, 1.0, 2)
    c = rng.uniform(abs(a - b) + 0.05, a + b)
    k = mass * rng.uniform(0.01, 0.1)
    return (f'<inertial><mass value="{mass:.17g}"/><origin xyz="{_xyz(rng.uniform(-0.2, 0.2, 3))}" '
            f'rpy="{_xyz(rng.uniform(-np.pi, np.pi, 3))}"/><inertia ixx="{k * a:.17g}" iyy="{k * b:.17g}" '
            f'izz="{k * c:.17g}" ixy="0" ixz="0" iyz="0"/></inertial>')


def random_tree(rng, name: str) -> str:
    """A URDF tree of 3 to 6 links hanging from a root link (no joint to the world: the loader adds the free one)."""
    count = int(rng.integers(3, 7))
    links = [f'<link name="l0">{_inertial(rng)}</link>']
    joints = []
    for i in range(1, count):
        parent = int(rng.integers(0, i))
        kind = rng.choice(["revolute", "continuous", "prismatic"])
        axis = rng.standard_normal(3)
        limit = '<limit lower="-3" upper="3" effort="10" velocity="10"/>' if kind != "continuous" else ""
        joints.append(f'<joint name="j{i}" type="{kind}"><parent link="l{parent}"/><child link="l{i}"/>'
                      f'<origin xyz="{_xyz(rng.uniform(-0.4, 0.4, 3))}" rpy="{_xyz(rng.uniform(-np.pi, np.pi, 3))}"/>'
                      f'<axis xyz="{_xyz(axis / np.linalg.norm(axis))}"/>{limit}</joint>')
        links.append(f'<link name="l{i}">{_inertial(rng)}</link>')
    return f'<robot name="{name}">' + "".join(links + joints) + "</robot>"


def pinocchio_configuration(pm, q: np.ndarray) -> np.ndarray:
    """Pinocchio's configuration of our q, joint by joint in Pinocchio's order (the loader's body order): a continuous
    joint's one angle as (cos, sin), every other block as it is."""
    out, k = [], 0
    for j in range(1, pm.njoints):
        joint = pm.joints[j]
        if joint.nq == 2 and joint.nv == 1:
            out += [np.cos(q[k]), np.sin(q[k])]
            k += 1
        else:
            out += list(q[k:k + joint.nq])
            k += joint.nq
    assert k == len(q)
    return np.array(out)


def _trees(tmp_path_factory):
    rng = np.random.default_rng(SEED)
    root = tmp_path_factory.mktemp("trees")
    paths = []
    for k in range(TREES):
        path = root / f"tree{k}.urdf"
        path.write_text(random_tree(rng, f"tree{k}"))
        paths.append(str(path))
    return paths


@pytest.fixture(scope="module")
def trees(tmp_path_factory):
    return _trees(tmp_path_factory)


@pytest.mark.parametrize("backend", backends.names())
def test_random_floating_urdf_trees_agree_with_pinocchio_free_flyer(trees, backend):
    formalism = backends.get(backend)
    for path in trees:
        model = cases.from_urdf(path, base="free")
        assert model.bodies[0].joint == "free" and model.source.root == "free"
        truth_model = pin.buildModelFromUrdf(path, pin.JointModelFreeFlyer())
        assert truth_model.nv == model.nv
        data = truth_model.createData()
        for s in sampling.sample_states(model, 4, SEED, model.name):
            q, v, u = (np.array(x) for x in (s.q, s.qd, s.u))
            split = formalism.split(model, q, v, u)
            for mine, tau in ((split.total, model.input_map @ u), (split.drift, np.zeros(model.nv))):
                truth = pin.aba(truth_model, data, pinocchio_configuration(truth_model, q), v, tau)
                error = np.abs(mine - truth).max() / max(1.0, np.abs(truth).max())
                assert error <= RELATIVE, (backend, path, s.index, error)
