"""Doctest namespace: examples in docstrings may use ``torch`` and every public optics name."""

import pytest
import torch

import optics


@pytest.fixture(autouse=True)
def _doctest_namespace(doctest_namespace):
    doctest_namespace["torch"] = torch
    for name in optics.__all__:
        doctest_namespace[name] = getattr(optics, name)
