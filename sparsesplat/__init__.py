"""sparsesplat: sparse-view 3D Gaussian Splatting (DNGaussian) as a service.

The distribution installs a single top-level import name, ``sparsesplat``. Its sub-packages are
the repository's top-level folders (``api``, ``client``, ``server``, ``worker``, ``engine``),
linked in here so the user's layout and a collision-free import name coexist:

- ``sparsesplat.api``    wire schemas (pydantic; no torch)
- ``sparsesplat.client`` Python SDK and CLI helpers (httpx; no torch)
- ``sparsesplat.server`` FastAPI application (no torch)
- ``sparsesplat.worker`` job execution (imports the engine)
- ``sparsesplat.engine`` the torch core
"""

__version__ = "0.1.0"
