"""``python -m lesmc`` runs the command line."""

from lesmc.cli.main import main

main()
