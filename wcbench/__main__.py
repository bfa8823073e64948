"""``python -m wcbench`` runs the command line."""

import sys

from wcbench.cli import main

sys.exit(main())
