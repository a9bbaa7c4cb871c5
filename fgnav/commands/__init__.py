"""One module per CLI subcommand. Each defines ``register(subparsers)`` which adds its
parser and sets ``func=run``; ``run(args)`` imports what it needs lazily so that
``fgnav --help`` stays fast. ``fgnav.cli`` discovers the modules here."""
