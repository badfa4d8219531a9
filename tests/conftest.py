"""Test set-up: geometry is checked in float64."""

import shutil

import jax
import pytest

jax.config.update("jax_enable_x64", True)


@pytest.fixture(scope="session")
def hugin_tools():
    """Skip unless Hugin's command-line tools are installed (`apt-get install hugin-tools`)."""
    if shutil.which("pano_trafo") is None:
        pytest.skip("Hugin's pano_trafo is not installed")


@pytest.fixture(autouse=True)
def _compiled_programs_stay_in_process(monkeypatch, tmp_path):
    """A command run in-process (rigjax's or learnstitch's ``cli.main``, ``setup_worker``) must not
    point this session's JAX at a cache folder (the user's, shared by the test workers), nor load
    later tests' programs from exports (rigjax.compiled): :func:`rigjax.compiled.persist` does
    nothing here. Tests of persistence run the command lines in processes of their own, with a
    temporary ``RIGJAX_CACHE_DIR``."""
    monkeypatch.setattr("rigjax.compiled.persist", lambda folder=None: tmp_path / "not-persisted")


@pytest.fixture(autouse=True)
def _caches_stay_in_the_session(monkeypatch, tmp_path_factory):
    """learnstitch's template cache (learnstitch.video.template) in a folder of the test session's,
    never the user's; the tests' command lines inherit it."""
    monkeypatch.setenv("LEARNSTITCH_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "learnstitch-cache"))
