import pytest

from ._helpers import make_files


@pytest.fixture(scope="session")
def head_files(tmp_path_factory):
    """(log path, identified path, SimulatedLog, RigidBodyModel, theta) of a 640-sample log."""
    return make_files(tmp_path_factory.mktemp("head"))
