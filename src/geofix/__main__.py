"""``python -m geofix`` runs the command line."""

from geofix.cli import main

main()
