"""The integration tables in tests/conftest.py name files and tests that exist, so that a
renamed test does not slip into `make test-fast` unseen."""

import ast

from tests.conftest import INTEGRATION_FILES, INTEGRATION_TESTS
from tests.support import REPO


def test_every_integration_file_exists():
    assert [path for path in INTEGRATION_FILES if not (REPO / path).is_file()] == []


def test_every_integration_test_is_defined_in_its_file():
    missing = {}
    for path, names in INTEGRATION_TESTS.items():
        tree = ast.parse((REPO / path).read_text())
        defined = {node.name for node in tree.body if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))}
        if names - defined:
            missing[path] = sorted(names - defined)
    assert missing == {}
