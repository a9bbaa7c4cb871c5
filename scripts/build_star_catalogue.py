#!/usr/bin/env python
"""Rebuild the run-time star catalogue from a checkout: ``python -m fgnav.vision.catalogue_build``."""

from fgnav.vision.catalogue_build import main

if __name__ == "__main__":
    raise SystemExit(main())
