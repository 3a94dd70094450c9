"""Repository-wide test settings."""

import os

from hypothesis import settings

# Locally, property tests draw new examples every run and so keep finding bugs; in CI
# (CI=true) the same examples every time, so that a result can be reproduced.
settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")

#: started first, so that under `-n 2` its real-time arm motions overlap the rest of the suite
LONGEST_FIRST = ("test_dry_run_from_the_command_line_runs_experiments_against_the_emulator",)


def pytest_collection_modifyitems(config, items):
    items.sort(key=lambda item: item.name not in LONGEST_FIRST)  # stable: the rest keep order
