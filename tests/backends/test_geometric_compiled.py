"""The geometric backend's compiled evaluation (formalisms/geometric.py, "Compiled evaluation").

* The C compiled from a Function gives what casadi's interpreter gives, to ``100 eps cond(M)`` of the scale of each
  quantity (the bound of tests/backends/test_split_batch.py on two correct solves of one problem), on a fixed base, a
  constrained mechanism, group joints (free and ball), a chart and a chart of the group; single states and batches.
* Without a compiler, with ``CROSSCHECK_COMPILE=0``, when the compiler fails, or for an operation without a C form,
  the Function stays interpreted and says why.
* The disk cache: a library found there is loaded without compiling; a broken one (bytes that do not match their
  digest, or that do not load) is compiled again; a cache that cannot be written costs only the compilation.
* A Function is compiled only once it has evaluated ``COMPILE_AFTER`` states and spent its estimated compilation
  interpreted.

Small models only: each compilation here takes a fraction of a second.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import cases
from crosscheck.checks import charts
from crosscheck import cli
from crosscheck.core import sampling
from formalisms import geometric as geo

#: Rounding allowed between the compiled and the interpreted answer, in units of ``cond(M)`` times the scale.
RTOL = 100 * np.finfo(float).eps
STATES = 6


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A scratch disk cache, no Function compiled yet in this process, compilation on from the first state."""
    monkeypatch.setenv("CROSSCHECK_CACHE", str(tmp_path))
    monkeypatch.setenv(geo.COMPILE_ENV, "1")
    monkeypatch.setattr(geo, "_COMPILED", {})
    monkeypatch.setattr(geo, "COMPILE_AFTER", 0)
    monkeypatch.setattr(geo, "COMPILE_SECONDS_PER_INSTRUCTION", 0.0)
    return tmp_path / "geometric"


def _joint_states(case: str):
    model = cases.load(case)
    drawn = sampling.sample_states(model, STATES, seed=11, case=case)
    return model, [(s.q, s.qd, s.u) for s in drawn]


def _chart_states(model, chart, rng):
    """``(p, pd, tau_p)`` in ``chart``: the pitch of a ZYX block kept away from gimbal lock."""
    return [(rng.uniform(-1.0, 1.0, model.nv), rng.uniform(-2.0, 2.0, model.nv), rng.uniform(-5.0, 5.0, model.nv))
            for _ in range(STATES)]


def _scenes():
    """``(label, model, chart, states)``: the split of ``states`` in ``chart`` (None: the joint or group chart)."""
    rng = np.random.default_rng(3)
    out = []
    for case in ("double_pendulum", "four_bar", "free_body", "ball_pendulum"):
        model, states = _joint_states(case)
        out.append((case, model, None, states))
    for case, name in (("double_pendulum", "nonlinear"), ("ball_pendulum", "zyx")):
        model = cases.load(case)
        chart = charts.get(name, model)
        out.append((f"{case} in {name}", model, chart, _chart_states(model, chart, rng)))
    return out


SCENES = _scenes()


def _split(model, chart, state):
    return geo.split(model, *state) if chart is None else geo.split_chart(model, chart, *state)


def _evaluated(monkeypatch, model, chart, states, compile_: str):
    """Every state's Split and, in the joint or group chart, the batch, with compilation on (``"1"``) or off."""
    monkeypatch.setenv(geo.COMPILE_ENV, compile_)
    geo._COMPILED.clear()
    splits = [_split(model, chart, s) for s in states]
    batch = None if chart is not None else geo.split_batch(model, *(np.array(x) for x in zip(*states)))
    return splits, batch, geo._compiled(model, chart).evaluate.evaluation


def _assert_close(got, want, scale, what):
    err = float(np.max(np.abs(np.asarray(got) - np.asarray(want)), initial=0.0))
    assert err <= RTOL * scale, f"{what}: compiled and interpreted differ by {err:.3g} (tol {RTOL * scale:.3g})"


@pytest.mark.parametrize("label, model, chart, states", SCENES, ids=[s[0] for s in SCENES])
def test_compiled_equals_interpreted(cache, monkeypatch, label, model, chart, states):
    interpreted, batch_i, how_i = _evaluated(monkeypatch, model, chart, states, "0")
    compiled, batch_c, how_c = _evaluated(monkeypatch, model, chart, states, "1")
    assert how_i.startswith("interpreted casadi SX") and how_c.startswith("compiled C"), (how_i, how_c)
    for i, (a, b) in enumerate(zip(compiled, interpreted)):
        accel, force = b.cond_M * b.accel_scale, b.cond_M * b.lam_scale
        for name in ("drift", "ctrl", "total"):
            _assert_close(getattr(a, name), getattr(b, name), accel, f"{label} state {i} {name}")
            if batch_c is not None:
                _assert_close(getattr(batch_c, name)[i], getattr(batch_i, name)[i], accel, f"{label} batch {i} {name}")
        if model.k:
            for name in ("lam", "lam_drift"):
                _assert_close(getattr(a, name), getattr(b, name), force, f"{label} state {i} {name}")
                _assert_close(getattr(batch_c, name)[i], getattr(batch_i, name)[i], force, f"{label} batch {i} {name}")
        _assert_close(a.kinetic_energy, b.kinetic_energy, b.cond_M * b.kinetic_energy, f"{label} state {i} T")


def test_compiled_code_can_differ(cache):
    """The comparison above sees a compiled Function that is not the interpreted one: the pendulum's C with one
    product turned into a sum gives other numbers."""
    model, states = _joint_states("double_pendulum")
    function = geo._compiled(model, None).evaluate.function
    source = geo._c_source(function)
    mul = next(line for line in source.splitlines() if "*" in line and line.startswith("  w["))
    broken = source.replace(mul, mul.replace("*", "+", 1), 1)
    library = geo._build(broken, [geo._compiler(), *geo.C_FLAGS], cache / "broken.so", function.nnz_out(0))
    P, PD = (np.array(x) for x in list(zip(*states))[:2])
    P = geo._arguments(model, P)                     # the points, then the world data the Function reads
    want = np.array(function.map(len(P))(P.T, PD.T)).T
    assert not np.allclose(library(P, PD), want, rtol=1e-6)
    assert np.array_equal(geo._build(source, [geo._compiler(), *geo.C_FLAGS], cache / "good.so",
                                     function.nnz_out(0))(P, PD), want)


def _pendulum_evaluator():
    model, states = _joint_states("double_pendulum")
    geo.split(model, *states[0])
    return geo._compiled(model, None).evaluate


def test_without_a_compiler_the_functions_stay_interpreted(cache, monkeypatch):
    monkeypatch.setattr(geo.shutil, "which", lambda name: None)
    assert geo.evaluation() == "interpreted casadi SX (no C compiler found: none of cc, gcc on the PATH)"
    assert _pendulum_evaluator().evaluation == geo.evaluation()
    assert not cache.exists()


def test_compile_env_0_keeps_the_functions_interpreted(cache, monkeypatch):
    monkeypatch.setenv(geo.COMPILE_ENV, "0")
    assert geo.evaluation() == "interpreted casadi SX (CROSSCHECK_COMPILE=0)"
    assert _pendulum_evaluator().evaluation == geo.evaluation()


def test_a_failing_compiler_warns_and_stays_interpreted(cache, monkeypatch):
    monkeypatch.setattr(geo, "C_FLAGS", (*geo.C_FLAGS, "--no-such-flag"))
    with pytest.warns(RuntimeWarning, match="failed with exit status .*no-such-flag.*stays interpreted"):
        evaluator = _pendulum_evaluator()
    assert evaluator.evaluation.startswith("interpreted casadi SX (") and "--no-such-flag" in evaluator.evaluation


def test_an_operation_without_c_form_stays_interpreted(cache):
    p, pd = ca.SX.sym("p", 2), ca.SX.sym("pd", 2)
    library, how = geo._native(ca.Function("f", [p, pd], [ca.exp(p[0]) * pd[1]]))
    assert library is None and how == "interpreted casadi SX (casadi operation OP_EXP has no C form here)"


def test_a_cached_library_is_loaded_without_compiling(cache, monkeypatch):
    _pendulum_evaluator()
    assert len(list(cache.glob("*.so"))) == 1 and len(list(cache.glob("*.sha256"))) == 1
    geo._COMPILED.clear()
    monkeypatch.setattr(geo.subprocess, "run", lambda *a, **k: pytest.fail("compiled although cached"))
    assert _pendulum_evaluator().evaluation.startswith("compiled C")


@pytest.mark.parametrize("broken", ["bytes", "library"])
def test_a_broken_cache_file_is_compiled_again(cache, broken):
    """A library whose bytes do not match their digest (a truncated or overwritten file), or whose bytes match but
    that does not load, is compiled again and replaced."""
    _pendulum_evaluator()
    (library,) = cache.glob("*.so")
    good = library.read_bytes()
    library.write_bytes(good[:len(good) // 2] if broken == "bytes" else b"not a shared library")
    if broken == "library":
        library.with_suffix(".sha256").write_text(geo.hashlib.sha256(library.read_bytes()).hexdigest())
    geo._COMPILED.clear()
    assert _pendulum_evaluator().evaluation.startswith("compiled C")
    assert geo.hashlib.sha256(library.read_bytes()).hexdigest() == library.with_suffix(".sha256").read_text()


def test_a_cache_that_cannot_be_written_costs_only_the_compilation(cache, monkeypatch, tmp_path):
    blocked = tmp_path / "a file"
    blocked.write_text("")
    monkeypatch.setenv("CROSSCHECK_CACHE", str(blocked))
    assert _pendulum_evaluator().evaluation.startswith("compiled C")


def test_a_function_is_compiled_after_compile_after_states(cache, monkeypatch):
    monkeypatch.setattr(geo, "COMPILE_AFTER", 5)
    model, states = _joint_states("double_pendulum")
    for q, qd, u in states[:4]:
        geo.split(model, q, qd, u)
    evaluator = geo._compiled(model, None).evaluate
    assert evaluator.evaluation == "interpreted casadi SX (not yet compiled)"
    geo.split(model, *states[4])
    assert evaluator.evaluation.startswith("compiled C")


def test_formalisms_command_says_how_geometric_evaluates(monkeypatch, capsys):
    monkeypatch.setenv(geo.COMPILE_ENV, "0")
    assert cli.main(["formalisms"]) == 0
    lines = capsys.readouterr().out.splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("geometric "))
    assert lines[at + 1].split() == ["evaluation:", "interpreted", "casadi", "SX", "(CROSSCHECK_COMPILE=0)"]



def test_a_function_is_compiled_once_its_interpreted_time_pays_for_the_compilation(cache, monkeypatch):
    """Enough states are not enough: the seconds spent interpreted must reach the estimated compilation, so a large
    model's few states never pay for a compilation that costs more than they do."""
    monkeypatch.setattr(geo, "COMPILE_AFTER", 1)
    monkeypatch.setattr(geo, "COMPILE_SECONDS_PER_INSTRUCTION", 1.0)  # hours for the pendulum's Function
    model, states = _joint_states("double_pendulum")
    for q, qd, u in states:
        geo.split(model, q, qd, u)
    evaluator = geo._compiled(model, None).evaluate
    assert evaluator.evaluation == "interpreted casadi SX (not yet compiled)"
    assert 0.0 < evaluator._seconds < evaluator.compile_estimate
    evaluator.compile_estimate = evaluator._seconds
    geo.split(model, *states[0])
    assert evaluator.evaluation.startswith("compiled C")
