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
def _compiled_programs_stay_in_process(monkeypatch):
    """A command run in-process (``cli.main``) must not point this session's JAX at a cache folder,
    nor load later tests' programs from exports (rigjax.compiled): tests of persistence run the
    command lines in processes of their own, with a temporary ``RIGJAX_CACHE_DIR``."""
    monkeypatch.setattr("rigjax.cli._enable_compilation_cache", lambda: None)


@pytest.fixture(autouse=True)
def _caches_stay_in_the_session(monkeypatch, tmp_path_factory):
    """learnstitch's template cache (learnstitch.video.template) and the compiled programs that
    learnstitch's commands keep (rigjax.compiled) in folders of the test session's (one per test
    worker), never the user's, which other workers and earlier runs share; the tests' command lines
    inherit them."""
    monkeypatch.setenv("LEARNSTITCH_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "learnstitch-cache"))
    monkeypatch.setenv("RIGJAX_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "rigjax-cache"))
