"""The initial Gaussians' points: the random box (``random_init.py``), dense points from a metric
depth prior (``dense_init.py``), and the choice between them and the scene's sparse points
(``initial_points.py``)."""
