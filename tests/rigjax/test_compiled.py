"""Compiled programs kept across processes (rigjax.compiled): what names a program, and what a
damaged store does."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from rigjax import compiled
from rigjax.camera.model import Camera
from rigjax.camera.panorama import Equirect
from rigjax.compiled import Program
from rigjax.optimiser.problem import padded_points
from rigjax.optimiser.residuals import LineGroups, PointArrays
from rigjax.pto.project import load_project

PROJECT = str(Path(__file__).parent / "data" / "golden_optimiser" / "linked_vabc.start.pto")
TYPES = (Camera, Equirect, PointArrays, LineGroups)


def test_a_programs_key_is_its_structure_not_its_values():
    program = Program("rigjax.optimiser.objective", "point_metrics", static=("projection",))
    project = load_project(PROJECT)
    cameras = project.cameras(host=True)
    key = program.key((cameras, np.zeros(4)), {"projection": None})
    moved = cameras._replace(yaw=cameras.yaw + 1.0)
    assert program.key((moved, np.ones(4)), {"projection": None}) == key  # other values
    assert program.key((cameras, np.zeros(8)), {"projection": None}) != key  # another shape
    assert program.key((cameras, np.zeros(4, np.int32)), {"projection": None}) != key  # another dtype
    assert program.key((cameras, np.zeros(4)), {"projection": 3}) != key  # another static argument
    assert program.key((cameras, (np.zeros(4),)), {"projection": None}) != key  # another structure


def _truncated(data: bytes) -> bytes:  # a process killed while writing, a full disk
    return data[: len(data) // 2]


def _flipped(data: bytes) -> bytes:  # a bad sector: the same length, one byte changed
    return data[: len(data) // 2] + bytes([data[len(data) // 2] ^ 0xFF]) + data[len(data) // 2 + 1 :]


@pytest.mark.parametrize("damage", [_truncated, _flipped])
def test_a_damaged_export_is_exported_again_with_a_warning(tmp_path, monkeypatch, damage):
    monkeypatch.setattr(compiled, "_exports", tmp_path)  # exports only: this session's XLA cache stays
    project = load_project(PROJECT)
    points, weight = padded_points(project, np.ones(len(project.control_points)))
    args = (project.cameras(host=True), points, project.canvas(host=True), weight)

    def metrics():  # as a new process would: nothing loaded yet
        program = Program("rigjax.optimiser.objective", "point_metrics", static=("projection",), types=TYPES)
        return np.asarray(program(*args, projection=None)[2])

    first = metrics()
    (export,) = tmp_path.glob("point_metrics-*.jaxexport")
    whole = export.read_bytes()
    export.write_bytes(damage(whole))
    with pytest.warns(UserWarning, match=f"{export}: cannot be read back"):
        second = metrics()
    np.testing.assert_array_equal(second, first)
    assert export.read_bytes() == whole  # written again, whole
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(metrics(), first)
