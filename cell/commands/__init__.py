"""CLI subcommands. Each module exposes ``add_parser(subparsers)``, which registers its parser and sets
``func`` (a callable taking the parsed args and returning the exit code)."""
