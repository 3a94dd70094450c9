"""Repository-wide test settings."""

import os

from hypothesis import settings

# Locally, property tests draw new examples every run and so keep finding bugs; in CI
# (CI=true) the same examples every time, so that a result can be reproduced.
settings.register_profile("ci", derandomize=True, deadline=None, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")
