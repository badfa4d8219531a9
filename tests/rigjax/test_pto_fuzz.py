"""The .pto reader and writer under seeded mutations of the golden projects (rigjax.pto.fuzz): every
input loads or is refused with a PtoError naming the file, quickly; every loaded project saves and
reloads to the same values, and an unedited one saves to its own text. `benchmarks/pto_fuzz.py`
runs a hundred thousand."""

from __future__ import annotations

from pathlib import Path

import pytest

from rigjax.pto import fuzz

GOLDEN = sorted((Path(__file__).parent / "data").glob("golden*/*.pto"))
INPUTS = 2000


def test_mutated_projects_load_or_are_refused_and_round_trip():
    texts = [path.read_bytes().decode() for path in GOLDEN]  # line ends as they are
    failures, outcomes = [], {"loaded": 0, "refused": 0}
    for seed in range(INPUTS):
        text = fuzz.mutate(texts[seed % len(texts)], seed)
        try:
            outcome = fuzz.check(text)
        except fuzz.FuzzFailure as failure:
            failures.append((seed, str(failure)))
            continue
        outcomes[outcome.status] += 1
        assert outcome.seconds < 0.25 + 0.05 * len(text) / 1024, (seed, outcome.seconds, len(text))
    assert not failures, failures[:5]
    # Both outcomes are common: the mutations reach the parser's checks and its writer.
    assert min(outcomes.values()) > INPUTS // 5, outcomes


def test_the_checker_catches_what_it_looks_for(monkeypatch):
    text = GOLDEN[0].read_text()
    assert fuzz.check(text).status == "loaded"
    monkeypatch.setattr(fuzz, "parse_project", lambda text, path: int("x"))
    with pytest.raises(fuzz.FuzzFailure, match="ValueError instead of a PtoError"):
        fuzz.check(text)
    monkeypatch.undo()
    project = fuzz.parse_project(text, "fuzz.pto")
    edited = project.replace(images=(project.images[0].replace(yaw=1.0), *project.images[1:]))
    monkeypatch.setattr(fuzz, "parse_project", lambda text, path: edited)
    with pytest.raises(fuzz.FuzzFailure, match="not written back as read"):
        fuzz.check(text)
