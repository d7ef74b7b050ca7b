"""Typer command functions of the MDRL core, registered on `drlaas` by drlaas/cli.py."""
