"""Shared pytest setup: the full Cusick dataset is visible only to tests marked `dataset`.

A user's clone has no ../shared beside it. Every test that is not marked runs with the dataset hidden
($DRAPELAB_CUSICK_DIR set to "", which paths.cusick_dataset_dir and the C++ test support read as "absent"; child
processes inherit it), i.e. exactly as it runs there, whether or not the dataset is on this machine. The tests marked
`@pytest.mark.dataset` see it when it is present and skip, saying why, when it is not; CI's second stage
(`./drapelab test --dataset-tests` on a clone without the dataset) runs just those again, so the whole suite is
checked in both conditions without running it twice."""
import pytest

from drapelab import paths


def pytest_configure(config):
    config.addinivalue_line("markers", "dataset: the test reads the full Cusick dataset when present (it skips, "
                                       "saying why, when absent); unmarked tests run with the dataset hidden")


@pytest.fixture(autouse=True)
def _dataset_only_where_marked(request, monkeypatch):
    if request.node.get_closest_marker("dataset") is None:
        monkeypatch.setenv(paths.DATASET_ENV, "")
    yield
