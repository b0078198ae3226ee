"""Sub-commands of ``uvd``: one module each, exposing ``register(subparsers)``."""
