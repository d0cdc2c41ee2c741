"""The compiled evaluation of the Euler–Lagrange backend (module docstring, "Compilation"): the generated C against the
interpreted Python of the same derivation, the fallback to the interpreted code, and the disk cache of the libraries.

* Agreement: every output (M, C qd, g, T, phi, Jc, Jcdot qd) of the compiled code equals the interpreted one's to
  100 eps cond(M) of that quantity's size, at single states (``math``) and in batches (numpy columns), on fixed-base,
  constrained and group-joint models and in two charts; the splits of ``split`` and ``split_batch`` too.
* Fallback: ``CROSSCHECK_COMPILE=0``, no compiler on PATH, a compiler that fails (a warning): the interpreted code,
  with the reason in the evaluator's description and in ``evaluation()``.
* Cache: a second "process" loads the library without compiling; a damaged or truncated library is compiled again; a
  cache that cannot be written only costs the compilation; two threads compiling the same entry at once both work.
"""

from __future__ import annotations

import math
import os
import threading

import numpy as np
import pytest
import symengine

import cases
from crosscheck.checks import charts
from crosscheck.core import sampling
from formalisms import euler_lagrange as el

EPS = np.finfo(float).eps
LABELS = ("M", "Cqd", "g", "T", "phi", "Jc", "bias", "Qext")


@pytest.fixture(autouse=True)
def scratch_cache(tmp_path, monkeypatch):
    """Every test derives and compiles into its own cache, and leaves nothing in the in-process one."""
    monkeypatch.setenv("CROSSCHECK_CACHE", str(tmp_path))
    monkeypatch.delenv(el.COMPILE_VARIABLE, raising=False)
    monkeypatch.setattr(el, "COMPILE_AFTER", 0)  # compiled from the first state
    el._compiled.cache_clear()
    yield tmp_path
    el._compiled.cache_clear()


def assert_agree(compiled, interpreted, what: str) -> None:
    """Each quantity of one state (:class:`el.Terms`, :class:`el.ConstraintTerms`) within 100 eps cond(M) of its own
    size (its largest entry)."""
    a, b = [[np.asarray(v, dtype=float) for v in (*terms[:4], *cons, *([] if terms.Qext is None else [terms.Qext]))]
            for terms, cons in (compiled, interpreted)]
    cond = np.linalg.cond(a[0])
    for label, x, y in zip(LABELS, a, b):
        if x.size:
            err, bound = np.abs(x - y).max(), 100 * EPS * cond * max(np.abs(y).max(), np.finfo(float).tiny)
            assert err <= bound, f"{what}: {label} differs by {err:.3g} > {bound:.3g}"


def assert_batch_agrees(model, compiled: np.ndarray, interpreted: np.ndarray, what: str) -> None:
    for i, (a, b) in enumerate(zip(compiled, interpreted)):
        assert_agree(el._unpack(model, a), el._unpack(model, b), f"{what}, state {i}")


def _pair(model, chart=None) -> tuple[el._Evaluator, el._Evaluator]:
    compiled = el._native(model, chart)
    assert compiled.description.startswith("compiled C (")
    return compiled, el._interpreted(model, chart, "the test's reference")


def _states(model, name: str, count: int = 5):
    drawn = sampling.sample_states(model, count, 11, name)
    return np.array([s.q for s in drawn], dtype=float), np.array([s.qd for s in drawn], dtype=float)


CASES = ("double_pendulum", "spatial_arm", "panda", "four_bar", "double_pendulum_circle", "ball_pendulum",
         "satellite_arm")


@pytest.mark.parametrize("name", CASES)
def test_compiled_code_agrees_with_the_interpreted_code(name):
    """Fixed-base (double pendulum, spatial arm, panda), constrained (four-bar, a point on a circle) and group joints
    (a ball joint; a free base with an arm, in local exponential coordinates): single states and a batch."""
    model = cases.load(name)
    compiled, interpreted = _pair(model)
    Q, QD = _states(model, name)
    for q, qd in zip(Q, QD):
        assert_agree(el._unpack(model, compiled.single(q, qd)), el._unpack(model, interpreted.single(q, qd)),
                     f"{name} at q = {q.tolist()}")
    assert_batch_agrees(model, compiled.batch(Q, QD), interpreted.batch(Q, QD), f"{name}, a batch")
    wrong = compiled.single(Q[0], QD[0])
    M = el._unpack(model, wrong)[0].M
    wrong[0] += 1000 * EPS * np.linalg.cond(M) * np.abs(M).max()  # M_00 off by ten times the bound: caught
    with pytest.raises(AssertionError, match="M differs by"):
        assert_agree(el._unpack(model, wrong), el._unpack(model, interpreted.single(Q[0], QD[0])), "a wrong answer")


@pytest.mark.parametrize("name, chart_name", [("spatial_arm", "affine"), ("four_bar", "affine"),
                                              ("satellite_arm", "zyx")])
def test_compiled_code_agrees_in_a_chart(name, chart_name):
    """A dense affine chart (every coordinate mixes all) and ZYX Euler angles of a free base (the whole q from psi)."""
    model = cases.load(name)
    chart = charts.get(chart_name, model, 0, name)
    compiled, interpreted = _pair(model, chart)
    for q, qd in zip(*_states(model, name)):
        p = chart.p_of(q)
        pd = charts.velocity_to_chart(chart, p, qd)
        assert_agree(el._unpack(model, compiled.single(p, pd)), el._unpack(model, interpreted.single(p, pd)),
                     f"{name} in {chart_name} at p = {p.tolist()}")


@pytest.mark.parametrize("name", ["spatial_arm", "four_bar"])
def test_split_and_split_batch_run_compiled_and_agree_with_the_interpreted_splits(name, monkeypatch):
    model = cases.load(name)
    drawn = sampling.sample_states(model, 4, 3, name)
    Q, QD, U = (np.array([getattr(s, f) for s in drawn], dtype=float) for f in ("q", "qd", "u"))
    compiled = [el.split(model, *args) for args in zip(Q, QD, U)], el.split_batch(model, Q, QD, U)
    assert el._compiled(model, None).description.startswith("compiled C (")
    monkeypatch.setenv(el.COMPILE_VARIABLE, "0")
    el._compiled.cache_clear()
    interpreted = [el.split(model, *args) for args in zip(Q, QD, U)], el.split_batch(model, Q, QD, U)
    assert el._compiled(model, None).description == "interpreted Python (CROSSCHECK_COMPILE=0)"
    for i, (a, b) in enumerate(zip(compiled[0], interpreted[0])):
        bound = 100 * EPS * a.cond_M * a.accel_scale
        for field in ("drift", "ctrl", "total"):
            assert np.abs(getattr(a, field) - getattr(b, field)).max() <= bound, f"state {i}: split's {field}"
            assert np.abs(getattr(compiled[1], field)[i] - getattr(b, field)).max() <= bound, f"state {i}: batch"


def test_the_c_emitter_writes_floating_point_arithmetic_only():
    """Integers become double literals (no integer division can happen), powers ``b*b``, ``1.0/b``, ``vsqrt``,
    ``vpow`` with the base named first, ``sin`` and ``cos`` the lane-by-lane ``vsin`` and ``vcos``."""
    a, b = symengine.symbols("a b")
    exprs = [2 * a + 3 * b, a ** 2, (a + b) ** 2, a ** -1, a ** symengine.Rational(1, 2), a ** -3,
             symengine.Rational(1, 3) * symengine.sin(a) + symengine.cos(b)]
    code = el._Source(exprs, el._C)
    assert [code.ref(e) for e in exprs] == [
        "((3.0*b) + (2.0*a))", "(a*a)", "(x0*x0)", "(1.0/a)", "vsqrt(a)", "vpow(a, -3.0)",
        "(vcos(b) + (0.3333333333333333*vsin(a)))"]
    assert code.statements == [("x0", "(b + a)")]
    with pytest.raises(ValueError, match="no C literal"):
        el._C.number(symengine.RealDouble(math.inf))


def test_no_compilation_falls_back_to_the_interpreted_code(monkeypatch, scratch_cache):
    """``CROSSCHECK_COMPILE=0`` and a machine without cc or gcc: the interpreted code, the reason said, no library."""
    model = cases.load("double_pendulum", m1=1.3)
    q, qd = np.array([0.3, -1.1]), np.array([0.7, 2.0])
    expected = el._unpack(model, el._interpreted(model, None, "reference").single(q, qd))
    monkeypatch.setenv(el.COMPILE_VARIABLE, "0")
    assert el.evaluation() == "interpreted Python (CROSSCHECK_COMPILE=0)"
    assert_agree(el.evaluate(model, q, qd), expected, "CROSSCHECK_COMPILE=0")
    monkeypatch.delenv(el.COMPILE_VARIABLE)
    monkeypatch.setattr(el.shutil, "which", lambda name: None)
    el._compiled.cache_clear()
    assert el.evaluation() == "interpreted Python (no C compiler found: neither cc nor gcc is on PATH)"
    assert el._compiled(model, None).description == el.evaluation()
    assert_agree(el.evaluate(model, q, qd), expected, "no compiler")
    assert not list(scratch_cache.rglob("*.so"))


def test_a_compiler_that_fails_warns_and_falls_back(monkeypatch):
    model = cases.load("double_pendulum", m1=1.4)
    monkeypatch.setattr(el, "_compiler", lambda: "false")
    with pytest.warns(RuntimeWarning, match="model 'double_pendulum': the C did not compile: false exited with"):
        evaluator = el._compiled(model, None)
    assert evaluator.description == "interpreted Python (the C did not compile: false exited with status 1)"
    assert np.isfinite(el.split(model, [0.3, -1.1], [0.7, 2.0], [1.0, 0.5]).drift).all()


def _library_path(model) -> os.PathLike:
    return el._cache_dir() / f"{el.cache_key(model)}.so"


def test_a_cached_library_is_loaded_without_compiling(monkeypatch):
    model = cases.load("double_pendulum", m1=1.5)
    q, qd = np.array([0.3, -1.1]), np.array([0.7, 2.0])
    first = el.evaluate(model, q, qd)
    assert el._intact(_library_path(model))
    el._compiled.cache_clear()

    def no_build(source):
        raise AssertionError("compiled although the library is cached")

    monkeypatch.setattr(el, "_build", no_build)
    assert_agree(el.evaluate(model, q, qd), first, "the cached library")


@pytest.mark.parametrize("damage", ["garbage", "truncated", "digest"])
def test_a_damaged_library_is_compiled_again(damage):
    """Garbage, the first half of the entry, or a whole library whose digest does not match: never loaded (a truncated
    library can crash the process that maps it), compiled again and rewritten."""
    model = cases.load("double_pendulum", m1=1.6)
    q, qd = np.array([0.3, -1.1]), np.array([0.7, 2.0])
    expected = el._unpack(model, el._interpreted(model, None, "reference").single(q, qd))
    el._library(model, None)
    path = _library_path(model)
    whole = path.read_bytes()
    broken = {"garbage": b"not a library", "truncated": whole[:len(whole) // 2],
              "digest": whole[:-1] + bytes([whole[-1] ^ 1])}[damage]
    path.write_bytes(broken)
    assert not el._intact(path)
    assert_agree(el.evaluate(model, q, qd), expected, f"after a {damage} library")
    assert el._compiled(model, None).description.startswith("compiled C (")
    assert el._intact(path) and path.read_bytes() != broken


def test_a_cache_that_cannot_be_written_only_costs_the_compilation(tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("CROSSCHECK_CACHE is a file")
    monkeypatch.setenv("CROSSCHECK_CACHE", str(blocker))
    model = cases.load("double_pendulum", m1=1.7)
    q, qd = np.array([0.3, -1.1]), np.array([0.7, 2.0])
    expected = el._unpack(model, el._interpreted(model, None, "reference").single(q, qd))
    assert_agree(el.evaluate(model, q, qd), expected, "an unwritable cache")
    assert el._compiled(model, None).description.startswith("compiled C (")


def test_two_compilations_of_the_same_entry_at_once_both_work(scratch_cache):
    """Each compiles in its own directory and renames its entry into place: both load, the entry is whole, and no
    temporary file is left."""
    model = cases.load("double_pendulum", m1=1.8)
    el.cached_source(model, None, "c")
    q, qd = np.array([0.3, -1.1]), np.array([0.7, 2.0])
    outcomes: list = []

    def compile_and_run():
        try:
            library, layout = el._library(model, None)
            outcomes.append(layout)
        except Exception as exc:  # the assertion below names it
            outcomes.append(exc)

    threads = [threading.Thread(target=compile_and_run) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert outcomes == [(2 + len(el._world_values(model)), 2, 8)] * 2, outcomes   # q and the world data
    assert el._intact(_library_path(model)) and not list(scratch_cache.rglob("*.tmp"))
    expected = el._unpack(model, el._interpreted(model, None, "reference").single(q, qd))
    assert_agree(el.evaluate(model, q, qd), expected, "after two compilations at once")


def test_the_compiled_code_checks_its_arguments():
    model = cases.load("double_pendulum", m1=1.9)
    compiled = el._native(model, None)
    with pytest.raises(ValueError, match=r"takes x of shape \(2,\) and xd of \(2,\), not \(3,\) and \(2,\)"):
        compiled.single(np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match=r"takes x of shape \(4, 2\)"):
        compiled.batch(np.zeros((4, 2)), np.zeros((4, 3)))
    assert math.isfinite(el.evaluate(model, np.zeros(2), np.zeros(2))[0].T)


def test_a_model_is_compiled_once_it_has_had_enough_states(monkeypatch, scratch_cache):
    """A gate's few states stay interpreted: the C is compiled on the state that reaches COMPILE_AFTER, and from then
    on that model in that chart runs compiled; a library already in the cache is loaded at once."""
    monkeypatch.setattr(el, "COMPILE_AFTER", 5)
    model = cases.load("double_pendulum", m1=1.7)
    q, qd = np.array([0.3, -1.1]), np.array([0.7, 2.0])
    for _ in range(4):
        el.evaluate(model, q, qd)
    assert el._compiled(model, None).description == "interpreted Python (compiled after 5 states)"
    assert not list(scratch_cache.rglob("*.so"))
    el.evaluate_batch(model, np.array([q]), np.array([qd]))
    assert el._compiled(model, None).description.startswith("compiled C (")
    el._compiled.cache_clear()
    assert el._compiled(model, None).description.startswith("compiled C (")


@pytest.mark.parametrize("name", ["spatial_arm", "slider_crank", "panda"])
def test_compiled_and_interpreted_code_round_alike(name):
    """The same operations in the same order (powers 2, -1 and 1/2 written out in both targets, never the C
    library's pow): one state's outputs are equal bit for bit, in the joint chart and an affine one, so a report does
    not depend on whether a library was cached."""
    model = cases.load(name)
    rng = np.random.default_rng(7)
    for chart in (None, charts.get("affine", model, 0, name)):
        compiled, interpreted = el._native(model, chart), el._interpreted(model, chart, "the test's reference")
        for _ in range(20):
            x = rng.uniform(-2.0, 2.0, model.nq if chart is None else model.n)
            xd = rng.uniform(-2.0, 2.0, model.n)
            assert np.array_equal(compiled.single(x, xd), interpreted.single(x, xd)), (name, chart, x, xd)
