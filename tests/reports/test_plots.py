"""The figures: the bench's charts render again from their saved JSON, the stability chart renders a small path, and
the stick figure of the mechanism puts the joints where the closed form of a planar two-link chain puts them."""

from __future__ import annotations

import numpy as np

import cases
from cases import Body, TaskPoint, build_model
from crosscheck.campaigns import bench, stability
from crosscheck.reports import bench_report, plots, stability_report
from crosscheck.engine import specs
from crosscheck.core.sampling import State

PNG = b"\x89PNG\r\n\x1a\n"


def _measurement(backend: str, scene: str, links, single: float, batch: float, error: float) -> bench.Measurement:
    errors = {"drift": error, "ctrl": error, "total": error}
    return bench.Measurement(backend, scene, links or 2, links, single, batch, 100, True, 1e-6, errors, errors, 0, 4)


def _results() -> bench.Results:
    measured = [_measurement(b, scene, links, t, t / 50, e)
                for b, scale in (("newton_euler", 1.0), ("pinocchio", 0.2))
                for scene, links, t, e in (("double_pendulum", None, 1e-4 * scale, 1e-15),
                                           ("n_link_pendulum n=2", 2, 1e-4 * scale, 2e-15),
                                           ("n_link_pendulum n=8", 8, 4e-4 * scale, float("nan")),
                                           ("n_link_pendulum n=12", 12, 9e-4 * scale, 0.0))]
    machine = {k: "x" for k in ("machine", "python", "numpy", "pinocchio", "casadi", "sympy")} | {"cpus": 2}
    return bench.Results("quick", machine, measured, [bench.Preparation("euler_lagrange", "panda", 1.0, 0.1)], [],
                         None, 3.0)


def test_bench_charts_render_again_from_the_saved_json(tmp_path):
    res = _results()
    saved = tmp_path / "speed_accuracy.json"
    saved.write_text(res.to_json() + "\n")
    assert bench.Results.from_json(saved.read_text()).to_json() == res.to_json()
    out = tmp_path / "again"
    report = bench_report.write_from_json(saved, out)
    assert report == out / "speed_accuracy.md" and "![time per state against error](speed_accuracy.png)" in \
        report.read_text()
    for name in ("speed_accuracy.png", "speed_scaling.png"):
        assert (out / name).read_bytes()[:8] == PNG
    assert (out / "speed_accuracy.json").read_text() == saved.read_text()
    assert [bench_report.family(m) for m in res.measurements[:4]] == ["double_pendulum"] + ["n_link_pendulum"] * 3
    nothing = bench.Results("quick", res.machine, [], [], [], None, 0.0)    # a bench interrupted before a measurement
    bench_report.chart_speed_accuracy(nothing, tmp_path / "empty.png")
    assert (tmp_path / "empty.png").read_bytes()[:8] == PNG


def test_stability_chart_renders_a_small_path(tmp_path):
    spec = specs.CaseSpec("double_pendulum")
    backends = ("newton_euler", "operational_space")
    points = tuple(stability.Point(x, spec, State(i, (0.5, x), (0.0, 0.0), (0.0, 0.0)), backends)
                   for i, x in enumerate((1.0, 1e-3, 1e-6)))
    path = stability.Path("theta2", "a small path", "theta2 (rad)", ("task",), points)
    measured = tuple(stability.Measurement(
        p, {"M": 30.0, "task": 1.0 / p.x ** 2}, {b: {"total": 1e-15 / p.x ** (b == backends[1])} for b in backends},
        {b: {"total": 1e-3} for b in backends}, {"total": 1e-12}, {b: "agree" for b in backends},
        {backends[1]: {"task": 1.0 / p.x ** 2}} if p.x < 1e-2 else {}, {}, (), 1e-3) for p in points)
    file = tmp_path / "stability_theta2.png"
    stability_report.plot(stability.PathResult(path, measured), file)
    assert file.read_bytes()[:8] == PNG


def test_stick_figure_points_of_a_planar_two_link_chain_are_the_closed_form(tmp_path):
    # links of lengths 0.7 and 0.4 about world z, hanging along -y: joint 2 at l1 (sin t1, -cos t1), the leaf's COM
    # (at its link's end) at that plus l2 (sin(t1 + t2), -cos(t1 + t2))
    l1, l2, t1, t2 = 0.7, 0.4, 0.3, -0.9
    z, inertia = (0.0, 0.0, 1.0), np.diag([0.01, 0.01, 0.02])
    model = build_model("two_link", [
        Body("upper", None, "revolute", z, 1.0, com=(0.0, -l1 / 2, 0.0), inertia=inertia),
        Body("fore", "upper", "revolute", z, 1.0, com=(0.0, -l2, 0.0), inertia=inertia, translation=(0.0, -l1, 0.0))],
        gravity=(0.0, -9.81, 0.0), task_points=[TaskPoint("hand", "fore", (0.1, -l2, 0.0))])
    origins, segments, ends, task = plots.stick_points(model, [t1, t2])
    elbow = l1 * np.array([np.sin(t1), -np.cos(t1), 0.0])
    np.testing.assert_allclose(origins, [np.zeros(3), elbow], atol=1e-15)
    assert segments == [(-1, 0), (0, 1)]
    np.testing.assert_allclose(ends, [elbow + l2 * np.array([np.sin(t1 + t2), -np.cos(t1 + t2), 0.0])], atol=1e-15)
    c, s = np.cos(t1 + t2), np.sin(t1 + t2)
    np.testing.assert_allclose(task, elbow + [0.1 * c + l2 * s, 0.1 * s - l2 * c, 0.0], atol=1e-15)
    file = plots.stick_figure(model, [t1, t2], tmp_path / "two_link.png", "two links")
    assert file.read_bytes()[:8] == PNG


def test_stick_figure_of_a_spatial_robot(tmp_path):
    panda = cases.load("panda")
    origins, segments, ends, task = plots.stick_points(panda, np.zeros(panda.nq))
    assert origins.shape == (panda.n, 3) and len(segments) == panda.n and len(ends) == 2   # two fingers
    np.testing.assert_allclose(origins[0], [0.0, 0.0, 0.333], atol=1e-12)   # panda_joint1: 0.333 m above the base
