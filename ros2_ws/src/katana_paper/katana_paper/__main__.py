import sys

from .curiosity_cli import main

sys.exit(main())
