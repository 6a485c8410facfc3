"""Alias so ``python -m sparsesplat.cli`` works like the ``sparsesplat`` command."""

import sys

from sparsesplat.client.cli import main

if __name__ == "__main__":
    sys.exit(main())
