"""``python -m lesmc`` runs the command line."""

from lesmc.cli.entry import main

main()
