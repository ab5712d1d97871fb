"""Subcommands of the ``assembly-agent`` console script, one module each.

Every module defines ``register(subparsers) -> None`` which adds its parser and sets
``func=<callable(args) -> int>`` as the parser default.
"""
