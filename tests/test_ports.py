"""The tests' port allocator is one allocator, however its module is reached."""

from __future__ import annotations

import importlib

from tests import ports


def test_conftest_as_pytest_loads_it_and_as_the_tests_import_it_share_one_allocator() -> None:
    as_loaded = importlib.import_module("conftest")
    as_imported = importlib.import_module("tests.conftest")
    assert as_loaded is not as_imported  # the two copies the allocator must not live in
    assert as_loaded.free_port is as_imported.free_port is ports.free_port


def test_ports_handed_out_in_a_row_differ() -> None:
    handed = [ports.free_port() for _ in range(50)]
    assert len(set(handed)) == len(handed)
