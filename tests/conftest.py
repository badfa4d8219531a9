"""Test set-up: geometry is checked in float64, and XLA compiles for a short wait rather than fast code."""

import gc
import os
import shutil
import subprocess
import sys
import tempfile

# Half of the suite's time is XLA compiling programs that then run for milliseconds: compiled at
# optimisation level 0 and through XLA's older loop emitters, an LM stage's program compiles about
# three times faster and runs about three times slower, and the suite takes about two thirds of
# the time. The code under test is the same; speed is measured by the benchmarks, which keep
# XLA's defaults. Set before JAX loads (XLA reads XLA_FLAGS when its CPU client starts), so the
# workers and the command lines the tests run inherit them.
_FAST_COMPILE = ("--xla_backend_optimization_level=0", "--xla_cpu_use_fusion_emitters=false")


def _known_to_xla(flag: str) -> bool:
    """Whether this jaxlib's XLA takes ``flag``: an unknown one in XLA_FLAGS aborts the process."""
    probe = "import jax; jax.numpy.zeros(1).block_until_ready()"
    env = {**os.environ, "XLA_FLAGS": flag, "JAX_PLATFORMS": "cpu"}
    try:
        return subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, timeout=120).returncode == 0
    except subprocess.TimeoutExpired:
        return False


# Flags XLA_FLAGS already names are left as they are: pytest's workers inherit the first process's.
_chosen = [flag for flag in _FAST_COMPILE if flag.split("=")[0] not in os.environ.get("XLA_FLAGS", "")]
if _chosen and not _known_to_xla(" ".join(_chosen)):  # one probe for all where XLA knows them all
    _chosen = [flag for flag in _chosen if _known_to_xla(flag)]
os.environ["XLA_FLAGS"] = " ".join([os.environ.get("XLA_FLAGS", ""), *_chosen]).strip()

# The programs one test compiles, the session's other tests (the other worker's, and this worker's
# after its programs were let go) load instead of compiling them again: one folder of XLA's
# persistent cache per session, made by the first process and inherited by pytest's workers, removed
# when that process ends. A fresh session (a clean checkout) starts with it empty. An entry read
# while the other worker still writes it is compiled again, with a warning.
_SESSION_CACHE = "RIGJAX_TEST_SESSION_XLA_CACHE"
if _SESSION_CACHE not in os.environ:
    os.environ[_SESSION_CACHE] = tempfile.mkdtemp(prefix="rigjax-tests-xla-")
    _CACHE_OWNER = True
else:
    _CACHE_OWNER = False

import jax
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_compilation_cache_dir", os.environ[_SESSION_CACHE])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)


def pytest_unconfigure(config):
    """The session's cache folder removed by the process that made it, after its workers are gone."""
    if _CACHE_OWNER:
        shutil.rmtree(os.environ[_SESSION_CACHE], ignore_errors=True)


@pytest.fixture(scope="session")
def hugin_tools():
    """Skip unless Hugin's command-line tools are installed (`apt-get install hugin-tools`)."""
    if shutil.which("pano_trafo") is None:
        pytest.skip("Hugin's pano_trafo is not installed")


@pytest.fixture(autouse=True)
def _compiled_programs_stay_in_process(monkeypatch):
    """A command run in-process (rigjax's or learnstitch's ``cli.main``) must not point this
    session's JAX at a cache folder, nor load later tests' programs from exports (rigjax.compiled):
    tests of persistence run the command lines in processes of their own, with a temporary
    ``RIGJAX_CACHE_DIR``."""
    monkeypatch.setattr("rigjax.cli._enable_compilation_cache", lambda: None)
    monkeypatch.setattr("learnstitch.cli._enable_compilation_cache", lambda: None)


@pytest.fixture(autouse=True)
def _caches_stay_in_the_session(monkeypatch, tmp_path_factory):
    """learnstitch's template cache (learnstitch.video.template) in a folder of the test session's,
    never the user's; and the compiled programs the command lines run as processes keep
    (rigjax.compiled) in one the session's workers share, never the user's, where earlier runs left
    theirs. The tests' command lines inherit both."""
    root = tmp_path_factory.getbasetemp()
    monkeypatch.setenv("LEARNSTITCH_CACHE_DIR", str(root / "learnstitch-cache"))
    shared = root.parent if os.environ.get("PYTEST_XDIST_WORKER") else root  # xdist: one basetemp per worker
    monkeypatch.setenv("RIGJAX_CACHE_DIR", str(shared / "rigjax-cache"))


# Half the kernel's default limit on a process's memory mappings (vm.max_map_count, 65530); one test
# file's programs fit on top of it.
_MAPPINGS_KEPT = 32768


def _mappings() -> int:
    """This process's memory mappings (Linux); without ``/proc`` a count above :data:`_MAPPINGS_KEPT`,
    so that programs are let go after every file."""
    try:
        with open("/proc/self/maps", "rb") as maps:
            return sum(1 for _ in maps)
    except OSError:
        return _MAPPINGS_KEPT + 1


@pytest.fixture(autouse=True, scope="module")
def _compiled_programs_released_when_mappings_pile_up():
    """After a test file, the session's compiled programs are let go (``jax.clear_caches``) once this
    worker holds more than :data:`_MAPPINGS_KEPT` memory mappings: XLA keeps each program's machine
    code in mappings of its own, and a worker that kept a whole session's programs reached the
    kernel's limit and died in the middle of a compilation. Below it, later files reuse the
    programs earlier files compiled."""
    yield
    if _mappings() > _MAPPINGS_KEPT:
        jax.clear_caches()
        gc.collect()
