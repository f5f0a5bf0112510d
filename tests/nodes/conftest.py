"""The end-to-end (slow) service tests start nodes: they get a warm kernel cache first
(except those marked ``cold_cache``, which start from an empty one on purpose)."""

import pytest


@pytest.fixture(autouse=True)
def _warm_kernels_for_services(request):
    if request.node.get_closest_marker("slow") and not request.node.get_closest_marker("cold_cache"):
        request.getfixturevalue("warm_kernels")
