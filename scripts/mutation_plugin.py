"""pytest plugin for scripts/mutation-study.

- With ``$MUTATION_COVERAGE_RC`` set (the study's map), while a test runs,
  ``$COVERAGE_PROCESS_START`` points at that configuration, so that a process the test
  launches (a command, ``mpiexec``'s ranks) is measured, and ``$MUTATION_TEST_CONTEXT``
  names the test (``nodeid|run``): the configuration reads it as that process's static
  context, so its lines are mapped to the test.
- At collection, with ``$MUTATION_FIXTURES`` set, every test's shared fixtures (scope
  above function, defined in tests/) are written there as JSON, ``{nodeid:
  ["name@baseid@instance", ...]}`` in collection order. Two tests that list the same key
  share one instance of that fixture, so a line run while one of them sets it up feeds
  both.
"""

import json
import os

import pytest


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item, nextitem):
    rc = os.environ.get("MUTATION_COVERAGE_RC")
    if not rc:
        return (yield)
    os.environ["MUTATION_TEST_CONTEXT"] = f"{item.nodeid}|run"
    os.environ["COVERAGE_PROCESS_START"] = rc
    try:
        return (yield)
    finally:
        os.environ.pop("MUTATION_TEST_CONTEXT", None)
        os.environ.pop("COVERAGE_PROCESS_START", None)


def pytest_collection_finish(session):
    out = os.environ.get("MUTATION_FIXTURES")
    if not out:
        return
    shared = {}
    for item in session.items:
        info = item._fixtureinfo
        keys = []
        for name in info.names_closure:
            definitions = info.name2fixturedefs.get(name)
            if not definitions or not definitions[-1].baseid:  # pytest's own (tmp_path_factory)
                continue
            fixture = definitions[-1]
            instance = {
                "module": item.nodeid.split("::")[0],
                "class": item.nodeid.rsplit("::", 1)[0],
            }.get(fixture.scope, "")
            if fixture.scope != "function":
                keys.append(f"{name}@{fixture.baseid}@{instance}")
        shared[item.nodeid] = keys
    with open(out, "w") as fh:
        json.dump(shared, fh)
