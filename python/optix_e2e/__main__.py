"""``python -m optix_e2e`` runs the ``optix`` command line."""

from .cli import main

if __name__ == "__main__":
    main()
