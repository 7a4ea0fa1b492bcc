"""pytest plugin for scripts/mutation-study: at collection, write every test's shared
fixtures (scope above function, defined in tests/) to $MUTATION_FIXTURES as JSON,
``{nodeid: ["name@baseid@instance", ...]}`` in collection order. Two tests that list the same
key share one instance of that fixture, so a line run while one of them sets it up feeds
both."""

import json
import os


def pytest_collection_finish(session):
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
    with open(os.environ["MUTATION_FIXTURES"], "w") as fh:
        json.dump(shared, fh)
