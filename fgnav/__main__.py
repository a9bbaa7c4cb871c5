import sys

from fgnav.cli import main

sys.exit(main())
