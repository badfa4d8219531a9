"""learnstitch.worker.setup_worker: torch's thread count on top of rigjax's set-up, and
OMP_WAIT_POLICY only where torch has not loaded OpenMP yet."""

from __future__ import annotations

import os
import subprocess
import sys

import torch

from learnstitch.worker import setup_worker


def test_a_fresh_process_gets_the_wait_policy_and_the_threads():
    code = (
        "import os, sys\n"
        "from learnstitch.worker import setup_worker\n"
        "assert setup_worker(torch_threads=1, omp_wait_policy='PASSIVE') is None\n"
        "import torch\n"
        "print(os.environ['OMP_WAIT_POLICY'], torch.get_num_threads())\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.split() == ["PASSIVE", "1"]


def test_a_process_with_torch_keeps_its_environment(monkeypatch):
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    threads = torch.get_num_threads()
    try:
        setup_worker(torch_threads=1, omp_wait_policy="PASSIVE")
        assert torch.get_num_threads() == 1 and "OMP_WAIT_POLICY" not in os.environ
    finally:
        torch.set_num_threads(threads)
