"""bench/robust_envelope.py: the sweeps hold the suite's values, each point perturbs what it names, and the
points are read back onto the right magnitudes with the nominal robot at each key's nominal value."""

from __future__ import annotations

import dataclasses

import pytest
from script_modules import load_bench

from bar_policy.robot.perturb_suite import SUITE

env = load_bench("robust_envelope")


def test_every_sweep_holds_its_suite_rows_value_and_gating() -> None:
    # Each single-key row of the suite (the combined row aside) is a point of its key's sweep, judged alike,
    # so the envelope and the suite table agree there. Not swept: the palm payload (the sweep's payload sits
    # at the fingertip), the observation delay and the pushes.
    by_key = {s.key: s for s in env.SWEEPS}

    def values(row):  # the perturbation's values, its spec's spelling aside (friction_nm=1 and =1.0 alike)
        return dataclasses.replace(row.perturbation, text="")

    points = env.sweep_rows()
    swept, not_swept = [], []
    for row in SUITE:
        if not row.spec or row.name == "combined":
            continue
        same = any(values(p) == values(row) and p.gating == row.gating for p in points)
        (swept if same else not_swept).append(row.name)
    assert not_swept == ["payload 0.5 kg palm", "obs delay 1 tick", "push 10 N"]
    # mass x0.8 and x1.2, fingertip payload, friction, damping, strength, delay, offset
    assert len(swept) == 8
    assert by_key["offset_rad"].gating == "none"  # invisible to any policy: reported, not judged


def test_rows_perturb_exactly_what_they_name() -> None:
    rows = env.sweep_rows(["payload_kg", "strength"])
    assert [r.name for r in rows] == [
        "nominal",
        "payload_kg 0.1",
        "payload_kg 0.3",
        "payload_kg 0.5",
        "payload_kg 0.75",
        "strength 0.6",
        "strength 0.7",
        "strength 0.8",
        "strength 0.9",
    ]
    assert rows[0].spec == ""
    p = rows[3].perturbation  # payload 0.5 kg at each fingertip, nothing else
    assert (p.payload_kg, p.payload_at, p.strength, p.mass_scale, p.friction_nm) == (
        0.5,
        "fingertip",
        1.0,
        1.0,
        0.0,
    )
    q = rows[5].perturbation
    assert (q.strength, q.payload_kg) == (0.6, 0.0)
    with pytest.raises(ValueError, match=r"unknown sweep key\(s\) \['mass'\]; valid: \['mass_scale'"):
        env.sweep_rows(["mass"])


def test_points_put_each_figure_at_its_magnitude_and_nominal_at_the_keys_nominal() -> None:
    # A made-up run of two sweeps (figures by hand): strength's nominal is 1.0, payload's 0 kg.
    rows = [
        {"name": "nominal", "verdict": "PASS", "metrics": {"median end cm": 0.26, "success %": 100.0}},
        {"name": "strength 0.6", "verdict": "MISS", "metrics": {"median end cm": 0.72, "success %": 80.0}},
        {"name": "strength 0.8", "verdict": "PASS", "metrics": {"median end cm": 0.35, "success %": 100.0}},
        {"name": "payload_kg 0.5", "verdict": "MISS", "metrics": {"median end cm": 1.74, "success %": 90.0}},
    ]
    pts = env.points(rows, "reach")  # reach: the median segment-end distance
    assert pts == {
        "payload_kg": [(0.0, 0.26, "PASS"), (0.5, 1.74, "MISS")],
        "strength": [(0.6, 0.72, "MISS"), (0.8, 0.35, "PASS"), (1.0, 0.26, "PASS")],
    }


def test_plot_draws_the_gates_line_and_the_points(tmp_path, monkeypatch) -> None:
    import matplotlib.axes

    lines: list[float] = []
    real = matplotlib.axes.Axes.axhline
    monkeypatch.setattr(
        matplotlib.axes.Axes, "axhline", lambda ax, y, **kw: lines.append(y) or real(ax, y, **kw)
    )
    pts = {"strength": [(0.6, 80.0, "MISS"), (1.0, 100.0, "PASS")]}
    out = tmp_path / "env.png"
    env.plot("piano", "x.onnx", pts, out)
    assert lines == [90.0]  # the piano gate's min_success_pct, F1 in % (tasks/piano/gate.py), one panel
    lines.clear()
    env.plot("reach", "x.onnx", pts, out)
    assert lines == [0.6]  # reach: the gate's max_median_end_cm (tasks/reach/gate.py), cm
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
