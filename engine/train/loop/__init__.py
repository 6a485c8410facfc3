"""The training loop: the :class:`~sparsesplat.engine.train.loop.trainer.Trainer` (set-up, one
iteration, the run, its checkpoint state) and the parts every run builds or may build around it:
densification, the divergence guard, the recorder (evaluation and the run's files), the
schedule clock and the progress events; ``parts.py`` says what a part is."""
