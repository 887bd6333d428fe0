"""One module per ``agrivio`` sub-command, each with ``register(subparsers)``."""
