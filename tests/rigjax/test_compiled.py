"""Compiled programs kept across processes (rigjax.compiled): what names a program, and what a
damaged store does."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rigjax.compiled import Program
from rigjax.pto.project import load_project

GOLDEN = Path(__file__).parent / "data" / "golden"
PROJECT = str(GOLDEN / "cube_rig_linked.pto")


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
def test_a_damaged_export_is_exported_again_with_a_warning(tmp_path, damage):
    exe = str(Path(sys.executable).with_name("rigjax"))
    env = dict(os.environ, RIGJAX_CACHE_DIR=str(tmp_path))

    def run():
        done = subprocess.run(
            [exe, "trafo", PROJECT, "0"], input="539.5 719.5\n", capture_output=True, text=True, env=env
        )
        assert done.returncode == 0, done.stderr
        return done

    first = run()
    (export,) = (tmp_path / "exports").glob("transform_batch-*.jaxexport")
    whole = export.read_bytes()
    export.write_bytes(damage(whole))
    second = run()
    assert second.stdout == first.stdout == "1799.500000 899.500000\n"
    assert f"{export}: cannot be read back" in second.stderr
    assert export.read_bytes() == whole  # written again, whole
    third = run()
    assert third.stdout == first.stdout and "cannot be read back" not in third.stderr
