"""`python -m katana_paper.docs_report`: the command line of `cli`."""

import sys

from .cli import main

sys.exit(main())
