"""The dataset's visibility in the suite (conftest.py): unmarked tests run as on a user's clone (no dataset), tests
marked `dataset` see it where it is, and every test file that reads the dataset marks its tests."""
import glob
import os
import re
import subprocess
import sys

import pytest

from drapelab import paths

HERE = os.path.dirname(os.path.abspath(__file__))
BESIDE = os.path.normpath(os.path.join(paths.repository_root(), "..", "shared", "data", "cusick"))


def test_an_unmarked_test_and_its_child_processes_do_not_see_the_dataset():
    assert paths.cusick_dataset_dir() is None
    child = subprocess.run([sys.executable, "-c", "from drapelab import paths; print(paths.cusick_dataset_dir())"],
                           capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path)))
    assert child.returncode == 0, child.stderr
    assert child.stdout.strip() == "None"


@pytest.mark.dataset
def test_a_marked_test_sees_the_dataset_where_it_is():
    given = os.environ.get(paths.DATASET_ENV)
    folder = given if given is not None else BESIDE
    present = bool(folder) and os.path.isfile(os.path.join(folder, "manifest.csv"))
    assert paths.cusick_dataset_dir() == (os.path.normpath(folder) if present else None)


def test_every_test_that_reads_the_dataset_is_marked():
    reads = re.compile(r"cusick_dataset_dir\(|require_cusick_dataset\(")
    for path in sorted(glob.glob(os.path.join(HERE, "test_*.py"))):
        if os.path.basename(path) == os.path.basename(__file__):
            continue
        text = open(path, encoding="utf-8").read()
        if reads.search(text):
            assert "pytest.mark.dataset" in text, (f"{os.path.basename(path)} reads the Cusick dataset: mark the tests "
                                                   "that do @pytest.mark.dataset (tests/python/conftest.py)")
