"""``python -m c2farm``: the ``c2farm`` command where its console script is not on PATH (see ``__main__``)."""
