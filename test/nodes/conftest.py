"""Fixtures of the node tests."""

import pytest
from executor_rig import Rig


@pytest.fixture
def rig(request):
    """``rig(domain_id, **params)``: an executor :class:`~executor_rig.Rig`, closed after the
    test (the learner and sim_robot tests define their own ``rig``)."""
    made = []

    def make(domain_id, **params):
        made.append(Rig(domain_id, **params))
        return made[-1]

    yield make
    for r in made:
        r.close()
