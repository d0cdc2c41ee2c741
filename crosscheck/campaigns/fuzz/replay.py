"""A saved finding evaluated again: its model, state, chart and frame rebuilt exactly, every backend compared as the
campaign did (``crosscheck replay``)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from cases.model import Model
from cases.serialize import model_from_dict
from crosscheck import backends
from crosscheck.campaigns.fuzz.chunk import evaluate
from crosscheck.campaigns.fuzz.settings import FuzzError
from crosscheck.campaigns.fuzz.storage import read_finding
from crosscheck.checks import charts, frames
from crosscheck.core.sampling import State
from crosscheck.engine.outcomes import StateOutcome


# ------------------------------------------------------------------------------------------------ replay, merge


def find(out: Path, finding: str) -> dict:
    """The saved finding with this ID (or unique ID prefix); :class:`FuzzError` listing the valid IDs otherwise."""
    ids = sorted(p.stem for p in (out / "findings").glob("*.json"))
    matches = [i for i in ids if i.startswith(finding)] if finding else []
    if len(matches) != 1:
        what = "matches several findings" if matches else "is not a finding"
        raise FuzzError(f"'{finding}' {what} in {out}; valid IDs: {', '.join(ids) or 'none (no findings saved)'}")
    return read_finding(out / "findings" / f"{matches[0]}.json")


def scene_of(finding: dict) -> tuple[Model, State, charts.Chart, frames.Frame]:
    """The model, state, chart and frame a finding was found at, rebuilt exactly."""
    model = model_from_dict(finding["model"])
    s = finding["state"]
    state = State(0, tuple(s["q"]), tuple(s["qd"]), tuple(s["u"]))
    chart = charts.get(finding["chart"]["name"], model, finding["chart"]["seed"])
    f = finding["frame"]
    frame = frames.Frame(f["name"], np.array(f["rotation"]), np.array(f["translation"]))
    return model, state, chart, frame


def replay(finding: dict, names: Sequence[str] | None = None) -> StateOutcome:
    """Evaluate the finding's state again, as the campaign did, with its backends (or ``names``)."""
    model, state, chart, frame = scene_of(finding)
    chosen = [backends.get(name) for name in (names or finding["backends"])]
    with np.errstate(all="ignore"):
        return evaluate(model, state, chart, frame, chosen, finding["checks"])
