from fgnav.cli import run

run()
