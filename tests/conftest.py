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
