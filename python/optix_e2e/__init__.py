"""optix-e2e: exact ray-traced PSFs for compound lenses and end-to-end camera design."""

__version__ = "0.1.0"
