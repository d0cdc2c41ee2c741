"""The backends' disk cache (``formalisms.cache``): bounded by ``CROSSCHECK_CACHE_LIMIT``, least recently used files
evicted first, a hit counts as a use; ``crosscheck cache`` shows it and ``--clear`` empties it. And the Euler–Lagrange
derivation shared by a model's moved scenes and its gravity-free copy (the world data are parameters)."""

from __future__ import annotations

import os

import numpy as np
import pytest

import cases
import formalisms.euler_lagrange as el
from crosscheck import cli
from crosscheck.checks import frames
from formalisms import cache as interface


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("CROSSCHECK_CACHE", str(tmp_path))
    monkeypatch.setattr(interface, "_MEASURED", {})
    monkeypatch.setattr(interface, "_WRITTEN", {})
    el._compiled.cache_clear()
    el._derived.cache_clear()
    yield tmp_path
    el._compiled.cache_clear()
    el._derived.cache_clear()


def _write(name: str, size: int, age: float):
    path = interface.cache_dir("test") / name
    interface.write_cache_file(path, b"x" * size)
    os.utime(path, (age, age))
    return path


def test_the_cache_evicts_the_least_recently_used_files_past_its_limit(cache, monkeypatch):
    monkeypatch.setenv(interface.CACHE_LIMIT_VARIABLE, "10K")
    old, used, new = _write("old", 3000, 1000.0), _write("used", 3000, 2000.0), _write("new", 3000, 3000.0)
    interface.used_cache_file(old)                      # a hit: now the most recently used
    last = interface.cache_dir("test") / "last"
    interface.write_cache_file(last, b"x" * 3000)       # 12,000 bytes > 10 KiB: down to 90 % of it
    assert {p.name for p in interface.cache_dir("test").iterdir()} == {"old", "new", "last"}
    assert sum(size for _, size, _ in interface.cache_files()) <= 0.9 * 10240


def test_the_file_just_written_is_kept_even_above_the_limit(cache, monkeypatch):
    monkeypatch.setenv(interface.CACHE_LIMIT_VARIABLE, "1K")
    path = interface.cache_dir("test") / "big"
    interface.write_cache_file(path, b"x" * 5000)
    assert path.read_bytes() == b"x" * 5000


@pytest.mark.parametrize("text, size", [("123", 123), ("2K", 2048), ("1.5M", 1572864), ("1G", 1 << 30), ("", 1 << 30)])
def test_the_limit_reads_sizes(monkeypatch, text, size):
    monkeypatch.setenv(interface.CACHE_LIMIT_VARIABLE, text)
    assert interface.cache_limit() == size


def test_a_bad_limit_is_a_usage_error(cache, monkeypatch, capsys):
    monkeypatch.setenv(interface.CACHE_LIMIT_VARIABLE, "lots")
    assert cli.main(["cases"]) == 2
    assert "CROSSCHECK_CACHE_LIMIT='lots' is not a size" in capsys.readouterr().err


def test_the_cache_command_shows_and_clears(cache, capsys):
    _write("a", 2048, 1000.0)
    assert cli.main(["cache"]) == 0
    out = capsys.readouterr().out
    assert str(cache) in out and "2.0 KiB in 1 files" in out and "test: 2.0 KiB" in out
    assert cli.main(["cache", "--clear"]) == 0
    assert not cache.exists() and "cleared" in capsys.readouterr().out


@pytest.mark.parametrize("name", ["double_pendulum_circle", "satellite_arm", "double_pendulum_spring", "rolling_disk"])
def test_moved_scenes_and_the_gravity_free_copy_share_the_derivation(cache, monkeypatch, name):
    """A moved scene (root placement, gravity, the constraints' and loads' world data moved) and a copy without
    gravity have the model's cache key; deriving is done once for the three, and each evaluates with its own world
    data: the moved scene's M, C qd, g and constraint terms equal the model's (the scene moves rigidly, gravity with
    it) although its code read other numbers, and the copy without gravity has no gravity term."""
    model = cases.load(name)
    moved = frames.move_scene(model, frames.sampled(0, name, 1)[0])
    weightless = frames.move_scene(model, frames.Frame("id", np.eye(3), np.zeros(3)))
    weightless = cases.build_model(model.name, list(weightless.bodies), gravity=np.zeros(3),
                                   input_map=model.input_map, task_points=list(model.task_points),
                                   constraints=list(model.constraints), loads=list(model.loads))
    assert el.cache_key(moved) == el.cache_key(model) == el.cache_key(weightless)
    derived = []
    monkeypatch.setattr(el, "derivation", lambda *a, _d=el.derivation, **k: derived.append(a[0].name) or _d(*a, **k))
    rng = np.random.default_rng(3)
    q = cases.configuration.random_configuration(model, rng, 1.0, 0.3)
    v = rng.normal(size=model.nv)
    here, there = el.evaluate(model, q, v), el.evaluate(moved, q, v)
    (_, _, g_free, *_), _ = el.evaluate(weightless, q, v)
    assert len(derived) == 1
    assert not np.allclose(el._world_values(moved), el._world_values(model))
    for a, b in zip([*here[0][:3], *here[1][1:]], [*there[0][:3], *there[1][1:]]):
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-12 * max(1.0, np.abs(a).max(initial=0.0)))
    if not model.loads and model.gravity.any():
        np.testing.assert_allclose(g_free, 0.0, atol=1e-12)
        assert np.abs(here[0].g).max() > 0.1


@pytest.mark.parametrize("name", ["double_pendulum_circle", "satellite_arm", "double_pendulum_tip_force",
                                  "rolling_disk"])
def test_moved_scenes_share_the_geometric_functions(name):
    """geometric's casadi Functions take the world data as parameters too: the moved scene evaluates the model's own
    Functions (one build), and its joint-space accelerations are the model's (the scene moves rigidly, gravity and
    the loads' world data with it); a copy without gravity accelerates otherwise."""
    from formalisms import geometric
    model = cases.load(name)
    moved = frames.move_scene(model, frames.sampled(1, name, 1)[0])
    assert geometric._compiled(moved, None) is geometric._compiled(model, None)
    rng = np.random.default_rng(5)
    q = cases.configuration.random_configuration(model, rng, 1.0, 0.3)
    v, u = rng.normal(size=model.nv), rng.normal(size=model.m)
    here, there = geometric.split(model, q, v, u), geometric.split(moved, q, v, u)
    np.testing.assert_allclose(there.total, here.total, rtol=0, atol=1e-10 * max(1.0, np.abs(here.total).max()))
    if model.gravity.any():
        weightless = cases.build_model(model.name, list(model.bodies), gravity=np.zeros(3),
                                       input_map=model.input_map, task_points=list(model.task_points),
                                       constraints=list(model.constraints), loads=list(model.loads))
        assert geometric._compiled(weightless, None) is geometric._compiled(model, None)
        assert not np.allclose(geometric.split(weightless, q, v, u).total, here.total)
