"""``python -m drlaas``: the same as the ``drlaas`` console script."""

from drlaas.cli import app

app()
