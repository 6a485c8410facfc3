"""``python -m sparsesplat`` is the ``sparsesplat`` command."""

import sys

from sparsesplat.client.cli import main

sys.exit(main())
